"""Exploration tours: the most area sensed on one discharge, with the way home always kept.

Problem statement (kept apart from how it is solved): from a start state (position ``s``,
energy already used ``E_0``, time ``t_0``, area already sensed) find a drivable closed walk
``s -> ... -> home`` with per-segment speeds that

    maximises   the area sensed: the free workspace within ``sensor_radius_m`` of the walk
    subject to  at every vertex v of the walk
                E_0 + E(s -> v) + E_home(v) + reserve(v) <= E_avail        (homing constraint)
                and the walk ends at home with  t_0 + duration <= time_limit_s

where ``E`` is the battery energy of the model (``physics.pathcost``) at the planned speeds, ``E_home(v)`` the energy
of the best roadmap return from ``v`` at the cruise speed and ``reserve(v)`` the scenario's
reserve rule for the energy spent so far plus the return (``confidence = p``: from the model's
predictive variance of that energy, so the return succeeds with probability >= p).

How it is solved: an energy roadmap (``planning.roadmap``) gives minimum-energy legs between
coverage candidates (sweep-lane pieces and viewpoints, ``planning.coverage``); an orienteering
heuristic (``planning.orienteering``: greedy insertion by new area per joule, 2-opt and or-opt)
chooses and orders them under an energy budget; the CasADi speed optimiser
(``planning.speed``) then chooses a speed per segment (energy-optimal, capped on sweep lanes so
the sensor keeps up); and the result is re-evaluated (``walk.evaluate_walk``): energies along the walk with
``path_energy`` at those speeds, the return from every vertex on the roadmap, the reserve from
the model. If any vertex breaks the homing constraint the budget is lowered by the deficit and
the tour re-chosen. Beside it, complete sweeps (``planning.sweeps``) are scored under the
closed-loop homing rule; the best one's prefix is checked the same way (``sweep_plan.sweep_tour``) and
the rest kept as the plan's continuation; ``plan_tour`` keeps whichever answer is expected to
sense more in closed loop. Why the answer is safe: feasibility is decided on the re-evaluated
walk, at every vertex, not on the heuristic's estimates; a plan is only returned when every
margin is >= 0 (a continuation is flown only under the live check).
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import replace

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from orange_plan.errors import InputError, PlanningError
from orange_plan.limits import check_roadmap_vertices
from orange_plan.mission import check_time_limit
from orange_plan.physics.pathcost import path_energy
from orange_plan.planning import orienteering
from orange_plan.planning.coverage import (
    DEFAULT_MAX_LANE_FRACTION,
    Candidates,
    check_sensor_radius,
    coverage_candidates,
    coverage_grid,
)
from orange_plan.planning.plan import Plan, StartState
from orange_plan.planning.reach import (
    Reachability,
    check_start_free,
    home_status,
    prepare_reach,
    query_points,
)
from orange_plan.planning.reserve import reserve_from
from orange_plan.planning.roadmap import add_vertices, energy_field
from orange_plan.planning.sweep_plan import route_after as route_after
from orange_plan.planning.sweep_plan import sweep_tour
from orange_plan.planning.walk import (
    BITSTAR_LEGS,
    BITSTAR_S,
    TourSetup,
    _finish,
    _per_metre,
    _time_left_s,
    _variance,
    drivable_m,
    drive,
    evaluate_walk,
    refine_legs,
)
from orange_plan.planning.walk import (
    Driven as Driven,
)
from orange_plan.planning.walk import driven_energy_J as driven_energy_J
from orange_plan.planning.walk import home_legs as home_legs
from orange_plan.planning.walk import min_energy_per_m as min_energy_per_m
from orange_plan.planning.walk import plan_return_probability as plan_return_probability
from orange_plan.planning.walk import sensing_speed_mps as sensing_speed_mps
from orange_plan.planning.walk import walk_vertices as walk_vertices

COST_MODES = ("physics", "distance")
MAX_CANDIDATES = 400
"""Candidates kept for the tour search (the best by area per joule of a round trip)."""
MAX_BUDGET_TRIES = 8
"""Times the budget is lowered when the re-evaluated walk breaks a homing constraint."""
TIME_TOLERANCE = 1e-6
"""Relative overrun of the time limit accepted as the optimiser's round-off [-]."""
TIME_HEADROOM = 0.003
"""Share of the time left a warm replan's search keeps back for the driven profile's ramps
and stops beyond the probe's estimate [-] (measured overruns on the campus example: up to
0.13 %; a cold plan keeps none: it costs 1-2 % of coverage on the time-limited campus)."""
K_HOME = 8
"""Roadmap vertices each walk vertex is joined to for its return home."""


def plan_tour(ctx, start: StartState | None = None, *, cost: str = "physics",
              n_vertices: int = 5000, seed: int = 0, progress=None,
              max_candidates: int = MAX_CANDIDATES, optimise_speed: bool = True,
              bitstar_s: float = BITSTAR_S, bitstar_legs: int = BITSTAR_LEGS,
              sweeps: bool = True) -> Plan:
    """Plan an exploration tour (see the module docstring).

    Parameters
    ----------
    ctx : Context (scenario, world, model)
    start : where the plan starts (default: home, nothing used, nothing covered)
    cost : "physics" (the scenario's energy model) or "distance" (a constant energy per metre
        on flat, windless default ground: the usual distance budget, for comparison)
    n_vertices : roadmap size
    seed : roadmap seed
    progress : callable(str) told what is being done, or None
    max_candidates : coverage candidates kept for the search
    optimise_speed : choose speeds with the CasADi optimiser (else the cruise speed)
    bitstar_s, bitstar_legs : BIT* budget per leg [s] and how many of the costliest legs it
        may refine (``refine_legs``); 0 turns refinement off
    sweeps : also start from complete sweeps (``sweep_tour``) and keep whichever of the
        sweep and the orienteering tour is expected to sense more in closed loop

    Raises
    ------
    InputError
        For an impossible request: roadmap vertices or a sensor radius beyond the size
        limits (``orange_plan.limits``), start not in free space, home unreachable from the start,
        no coverage candidate that can be visited with the way home kept, a time limit already
        spent.
    """
    t0 = _time.perf_counter()
    step = progress or (lambda text: None)
    if cost not in COST_MODES:
        raise InputError(f"cost = {cost!r} must be one of {COST_MODES}")
    check_roadmap_vertices(n_vertices)
    start = start or StartState()
    planning_ctx = ctx if cost == "physics" else distance_context(ctx)
    step("building the energy roadmap")
    setup = tour_setup(planning_ctx, start, n_vertices, seed, max_candidates, step)
    try:
        toured = search_tour(planning_ctx, setup, start, t0=t0, step=step,
                             optimise_speed=optimise_speed, bitstar_s=bitstar_s,
                             bitstar_legs=bitstar_legs, seed=seed)
    except (InputError, PlanningError) as exc:  # a sweep may still fit where no tour does
        if not sweeps:
            raise
        toured, failure = None, exc
    swept = None
    if sweeps:
        step("complete sweeps at every angle and lane order")
        try:
            swept = sweep_tour(planning_ctx, setup, start, t0=t0, optimise_speed=optimise_speed)
        except PlanningError:  # no sweep joins up on this roadmap: the tour search's answer
            swept = None
    if toured is None and swept is None:
        raise failure
    return max((p for p in (toured, swept) if p is not None), key=expected_coverage_m2)


def expected_coverage_m2(plan: Plan) -> float:
    """Area a plan is expected to sense when flown in closed loop [m^2]: its continuation's
    expected extent, else the plan's own (guaranteed) coverage."""
    summary = plan.summary or {}
    return float(summary.get("closed_loop_coverage_m2", summary.get("coverage_m2", 0.0)))


def search_tour(ctx, setup: TourSetup, start: StartState, *, t0: float, step=None,
                optimise_speed: bool = True, bitstar_s: float = BITSTAR_S,
                bitstar_legs: int = BITSTAR_LEGS, seed: int = 0, probe=None,
                time_headroom: float = 0.0) -> Plan:
    """The tour search on a prepared setup: orienteering under the budgets, BIT* on the
    costliest legs, speeds, and the exact per-vertex check, the budget lowered by any deficit
    until every vertex keeps its margin (see the module docstring)."""
    step = step or (lambda text: None)
    reach = setup.reach
    remaining = reach.energy_available_J - reach.energy_used_J
    reserve_share, time_factor = _probe(setup) if probe is None else probe
    # The probe's factor comes from one trip; a whole tour's ramps and stops differ by a
    # fraction of a percent, which can fail the exact time check and cost a second search:
    # a replan, which must be quick, keeps ``time_headroom`` of the time back instead.
    time_factor *= 1.0 + time_headroom
    reserve_guess = reserve_share * remaining
    budget = remaining - reserve_guess
    time_left = _time_left_s(ctx, start)
    budget_s = time_left / time_factor
    last_error = None
    for attempt in range(MAX_BUDGET_TRIES):
        if budget <= 0 or budget_s <= 0:
            return _too_small(ctx, reach, last_error)
        step(f"choosing candidates (budget {budget / 1e3:,.1f} kJ)")
        problem = replace(setup.problem, budget_J=budget, budget_s=budget_s)
        tour = orienteering.solve(problem, step)
        if not tour.nodes:
            return _too_small(ctx, reach, last_error)
        step("BIT* on the costliest legs")
        walk_setup, ids, refined = refine_legs(setup, tour.nodes, bitstar_s, bitstar_legs, seed)
        step(f"speeds and homing check on {len(ids)} vertices")
        plan, variance = evaluate_walk(ctx, walk_setup, ids, start, optimise_speed,
                                       time_factor)
        energy_short = -float(plan.margin_J.min())
        overrun_s = float(plan.t_s[-1]) - start.time_s - time_left
        in_time = check_time_limit(float(plan.t_s[-1]) * (1 - TIME_TOLERANCE),
                                   ctx.scenario.mission.time_limit_s).within
        if energy_short <= 0 and in_time:
            waypoints = setup.candidates.anchor_xy_m[[i for i, _ in tour.nodes]]
            plan = _finish(ctx, walk_setup, plan, waypoints, variance, start, t0)
            plan.summary["legs_refined_by_bitstar"] = refined
            return plan
        last_error = f"{max(energy_short, 0):.3g} J short, {max(overrun_s, 0):.3g} s over"
        # Cut by the deficit plus a slice that doubles with every try: a new tour may have a
        # deficit of its own, and the loop must end.
        if energy_short > 0:
            budget -= 1.05 * energy_short + 2**attempt * 1e-3 * remaining
        if not in_time:
            budget_s -= 1.5 * max(overrun_s, 0.0) + 2**attempt * 1e-2 * time_left
    raise PlanningError(f"no tour kept the homing constraint at every vertex after "
                        f"{MAX_BUDGET_TRIES} budget cuts ({last_error})")


def _too_small(ctx, reach: Reachability, last_error) -> None:
    """No candidate fits: the request itself is infeasible (exit 2), said in one line."""
    remaining = reach.energy_available_J - reach.energy_used_J
    head = (f"{ctx.scenario.name}: no coverage candidate can be visited with the way home and "
            "the reserve kept")
    if remaining <= 0:
        raise InputError(f"{head}: the energy used ({reach.energy_used_J / 1e3:,.4g} kJ) "
                         f"already exceeds the usable {reach.energy_available_J / 1e3:,.4g} kJ")
    detail = f"; the smallest tour was {last_error}" if last_error else ""
    raise InputError(
        f"{head} ({remaining / 1e3:,.3g} kJ left of {reach.energy_available_J / 1e3:,.3g}"
        f" kJ): the battery is too small to leave home, or the time limit is too short{detail}")


class TourPlanner:
    """Plans a tour, then replans from later states on the same roadmap and candidate legs.

    The first ``plan`` builds the setup (roadmap, fields, candidates, leg matrices: most of a
    plan's time). Later calls reuse it (``warm_setup``): the robot's position joins the
    roadmap as one vertex with one Dijkstra, the leg energies are rescaled to the current
    model, and only the search and the exact check run again. The exact check is the same as
    a cold plan's, with the current model, so a warm plan is as safe; the reuse only costs
    optimality where the model's change would have moved the roadmap's paths. A changed world
    (a map update: another map ``version``) is planned cold.

    Parameters
    ----------
    ctx : Context of the first plan (its world is kept; later models may differ)
    n_vertices, seed, max_candidates : as ``plan_tour``
    search : keyword arguments of ``search_tour`` (optimise_speed, bitstar_s, bitstar_legs)
    """

    def __init__(self, ctx, *, n_vertices: int = 5000, seed: int = 0,
                 max_candidates: int = MAX_CANDIDATES, **search):
        self.ctx = ctx
        self.n_vertices, self.seed, self.max_candidates = n_vertices, seed, max_candidates
        self.search = {"seed": seed, **search}
        self.setup: TourSetup | None = None

    def plan(self, start: StartState | None = None, model=None, world=None, conditions=None,
             progress=None) -> Plan:
        """A tour from ``start`` with ``model``, ``world`` and ``conditions`` (default: the
        context's). A world with another map version (obstacles, no-go zones added) than the
        setup's is planned cold."""
        t0 = _time.perf_counter()
        start = start or StartState()
        ctx = replace(self.ctx, model=model or self.ctx.model, world=world or self.ctx.world,
                      conditions=conditions or self.ctx.conditions)
        step = progress or (lambda text: None)
        if (self.setup is not None
                and ctx.world.map.version != self.setup.reach.exact.world.map.version):
            self.ctx, self.setup = ctx, None
        if self.setup is None:
            self.setup = tour_setup(ctx, start, self.n_vertices, self.seed,
                                    self.max_candidates, step)
            self.probe = _probe(self.setup)
            setup = self.setup
            headroom = 0.0  # a first plan may search twice: it is not made mid-mission
        else:  # the first plan's budget guesses serve: the exact check corrects them
            setup = warm_setup(self.setup, ctx, start)
            headroom = TIME_HEADROOM
        return search_tour(ctx, setup, start, t0=t0, step=step, probe=self.probe,
                           time_headroom=headroom, **self.search)


def warm_setup(setup: TourSetup, ctx, start: StartState) -> TourSetup:
    """``setup`` re-aimed at a new start state and model (see ``TourPlanner``)."""
    reach = setup.reach
    old_model = reach.fast.model
    fast, exact = (replace(c, model=ctx.model, world=ctx.world, conditions=ctx.conditions)
                   for c in (reach.fast, reach.exact))
    home = np.asarray(reach.home_xy_m)
    xy = home if start.xy_m is None else np.asarray(start.xy_m, float)
    check_start_free(ctx.world, xy)
    roadmap = add_vertices(reach.fast, setup.roadmap, xy[None, :])
    vertex = roadmap.n_vertices - 1
    dist, pred = dijkstra(roadmap.graph(), directed=True, indices=[vertex],
                          return_predecessors=True)
    point_vertex = np.r_[vertex, setup.point_vertex[1:]]
    if not np.isfinite(dist[0, setup.point_vertex[1]]):
        raise InputError(f"home is not reachable on the roadmap from ({xy[0]:g}, {xy[1]:g}) m")
    scale = _per_metre(ctx.model, ctx) / _per_metre(old_model, ctx)
    p = setup.problem
    travel_J, travel_s = p.travel_J * scale, p.travel_s.copy()
    travel_J[0] = dist[0, point_vertex] * scale
    travel_s[0] = _leg_times(ctx, fast.speed_mps, roadmap.xy_m, pred)[0, point_vertex]
    travel_J[:, 0] = travel_s[:, 0] = np.inf  # nothing returns to the start
    grid = setup.grid
    covered = (np.zeros(len(grid.xy_m), bool) if start.covered is None
               else _mask(grid, grid.cells_in(start.covered)))
    problem = replace(p, travel_J=travel_J, travel_s=travel_s, service_J=p.service_J * scale,
                      covered=covered)
    predecessors = np.pad(setup.predecessors, ((0, 0), (0, 1)), constant_values=-9999)
    predecessors[0] = pred[0]
    # a replan reads the field's energies and paths only (returns are re-evaluated exactly)
    to_home = energy_field(roadmap, roadmap.home_index, towards=True, with_gradient=False)
    warm = replace(reach, fast=fast, exact=exact, roadmap=roadmap, start_index=vertex,
                   energy_used_J=float(start.energy_used_J))
    return replace(setup, reach=warm, problem=problem, predecessors=predecessors,
                   point_vertex=point_vertex, roadmap=roadmap, to_home=to_home)


def distance_context(ctx):
    """The scenario on flat, windless default ground: energy per metre constant everywhere.

    Planning with it is the common practice of a distance budget (range = energy / energy per
    metre) that ignores grades, surfaces and wind; ``bench plan`` compares it with the
    physics-based plan when both are flown under the same truth.
    """
    world = ctx.world
    flat_map = replace(world.map, elevation=None, surfaces=())
    flat_world = replace(world, map=flat_map)
    return replace(ctx, world=flat_world, conditions=ctx.conditions.with_wind((0.0, 0.0)))


def tour_speed_mps(ctx, start: StartState) -> float:
    """Cruise speed of the tour search: the one that lets the robot drive farthest [m/s].

    On energy alone that is the simplified range's ``v_opt`` (Eq. 6). Under a time limit
    a faster speed may drive farther, ``min(E_left / e(v), v D T_left)``, where ``e(v)`` is
    the energy per metre on flat default ground: the speed maximising that on
    ``[v_opt, v_max]`` is taken (the speed optimiser later tunes each segment).
    """
    from orange_plan.physics.range import farthest_speed_mps

    v_opt = ctx.cruise_speed_mps
    limit = ctx.scenario.mission.time_limit_s
    if limit is None:
        return v_opt
    return farthest_speed_mps(lambda v: _per_metre(ctx.model, ctx, v), _motion_energy_guess(
        ctx, start), max(limit - start.time_s, 0.0), ctx.conditions.duty_cycle, v_opt,
        ctx.scenario.robot.v_max_mps)


def _motion_energy_guess(ctx, start: StartState) -> float:
    """Energy left for driving once the reserve is set aside, guessed before any path exists
    [J] (``ReserveRule.budget_guess_J``: a confidence reserve from the run-to-run spread)."""
    sc = ctx.scenario
    available = sc.battery.usable_J
    return reserve_from(sc).budget_guess_J(available - start.energy_used_J, available,
                                           ctx.model.discrepancy_rel_sd)


# --- set-up: roadmap, candidates, legs ------------------------------------------------------


def tour_setup(ctx, start: StartState, n_vertices: int, seed: int, max_candidates: int,
               step) -> TourSetup:
    """Roadmap and fields, coverage candidates that fit the battery, and their leg matrices."""
    check_roadmap_vertices(n_vertices)  # sizes first: nothing is built before they pass
    check_sensor_radius(ctx.world, ctx.scenario.mission.sensor_radius_m)
    _check_not_boxed_in(ctx)
    reach = prepare_reach(ctx, start.xy_m, start.energy_used_J, n_vertices=n_vertices, seed=seed,
                          speed_mps=tour_speed_mps(ctx, start), with_gradient=True)
    home = home_status(reach)
    if not home.reachable:
        if home.energy_to_home_J is None:
            raise InputError("home is not reachable from the start (boxed in by obstacles or "
                             "no-go zones)")
        raise InputError(f"the start cannot get home with its reserve: "
                         f"{home.energy_to_home_J:,.0f} J to home + {home.reserve_J:,.0f} J "
                         f"reserve > {reach.energy_available_J - reach.energy_used_J:,.0f} J left")
    step("coverage candidates")
    r = ctx.scenario.mission.sensor_radius_m
    grid = coverage_grid(ctx.world, r)
    covered = (np.zeros(len(grid.xy_m), bool) if start.covered is None
               else _mask(grid, grid.cells_in(start.covered)))
    cands = select_candidates(ctx, reach, grid, covered, max_candidates, _time_left_s(ctx, start))
    step(f"energy legs between {cands.n} candidates")
    return _legs(ctx, reach, cands, grid, covered)


def _check_not_boxed_in(ctx) -> None:
    """Refuse a home whose free pocket is smaller than one footprint: nothing to explore."""
    import shapely

    free = ctx.world.map.free_space
    home = shapely.Point(ctx.world.home_xy_m)
    pocket = next((g for g in getattr(free, "geoms", [free]) if g.intersects(home)), None)
    r = ctx.scenario.mission.sensor_radius_m
    disc_m2 = math.pi * r * r  # inf, not OverflowError as r**2 raises, for r = 1e200 m
    if pocket is None or pocket.area >= disc_m2:
        return
    if pocket.area >= free.area * (1 - 1e-9):  # nothing walls home in: the footprint is huge
        raise InputError(f"mission.sensor_radius_m = {r:g} m: one sensor footprint "
                         f"({disc_m2:.3g} m^2) is larger than the whole free area "
                         f"({free.area:.3g} m^2); nothing to explore")
    raise InputError(f"home is boxed in: the free area around it is {pocket.area:.3g} m^2 "
                     f"(of {free.area:.3g} m^2), less than one sensor footprint "
                     f"({disc_m2:.3g} m^2); nothing to explore")


def _mask(grid, cells) -> np.ndarray:
    mask = np.zeros(len(grid.xy_m), bool)
    mask[cells] = True
    return mask


def select_candidates(ctx, reach: Reachability, grid, covered, cap: int,
                      time_left_s: float = np.inf) -> Candidates:
    """Sweep-lane pieces whose round trip fits, viewpoints where lanes leave pockets, at most
    ``cap`` in all (the best by new area per joule of a round trip).

    Lanes tile the free space at the least driving per square metre, so they come first.
    Lane pieces are made long enough that the distance the robot can drive (``drivable_m``)
    spans at most half of the lane budget, so the search always has twice the choice it can
    use, without a flood of tiny pieces on a large battery. Viewpoints are kept only where
    they add at least a quarter of a footprint beyond the lanes. "Fits" means the candidate's
    own round trip fits the energy left and, under a time limit, its straight-line round trip
    at v_max fits the time left (a lower bound on any real round trip's time, so no
    reachable candidate is dropped).
    """
    r = ctx.scenario.mission.sensor_radius_m
    lane_cap = int(0.75 * cap)
    max_lane = max(DEFAULT_MAX_LANE_FRACTION * r, 2.0 * drivable_m(ctx, reach, time_left_s)
                   / lane_cap)
    cands = coverage_candidates(ctx.world, grid, r, max_lane_m=max_lane)
    trip = round_trip_J(reach, cands)
    fits = np.isfinite(trip) & (trip < reach.energy_available_J - reach.energy_used_J)
    fits &= _within_time(ctx, reach, cands, time_left_s)
    lane = cands.kind == "lane"
    value = cands.value_m2(covered, grid)
    score = value / np.maximum(trip, 1e-9)
    lanes = np.flatnonzero(lane & fits & (value > 0))
    lanes = lanes[np.argsort(-score[lanes], kind="stable")[:lane_cap]]
    with_lanes = covered.copy()
    for k in lanes:
        with_lanes[cands.cells[k]] = True
    residual = cands.value_m2(with_lanes, grid)
    pockets = np.flatnonzero(~lane & fits & (residual >= 0.25 * np.pi * r**2))
    pockets = pockets[np.argsort(-score[pockets], kind="stable")[:cap - len(lanes)]]
    if len(lanes) + len(pockets) == 0:
        raise InputError(f"{ctx.scenario.name}: no coverage candidate can be visited with the "
                         "way home and the reserve kept: "
                         + _why_no_candidate(ctx, reach, cands, trip, value, time_left_s))
    return cands.subset(np.sort(np.r_[lanes, pockets]))


def _why_no_candidate(ctx, reach: Reachability, cands: Candidates, trip: np.ndarray,
                      value: np.ndarray, time_left_s: float) -> str:
    """Which of energy, time or new area left no candidate, with the figures that show it."""
    left = reach.energy_available_J - reach.energy_used_J
    by_energy = np.isfinite(trip) & (trip < left)
    if not by_energy.any():
        cheapest = np.min(trip[np.isfinite(trip)], initial=np.inf)
        need = (f"the cheapest round trip to one needs {cheapest / 1e3:,.3g} kJ"
                if np.isfinite(cheapest) else "none can be reached")
        return (f"the battery is too small to leave home ({need}; {left / 1e3:,.3g} kJ left of "
                f"{reach.energy_available_J / 1e3:,.3g} kJ)")
    by_time = _within_time(ctx, reach, cands, time_left_s)
    if not (by_energy & by_time).any():
        quickest = np.min(_round_trip_s(ctx, reach, cands)[by_energy])
        return (f"the time limit is too short (mission.time_limit_s = "
                f"{ctx.scenario.mission.time_limit_s:g} s leaves {time_left_s:g} s; the quickest "
                f"round trip to one takes {quickest:,.3g} s at v_max)")
    return "every area within reach is already covered"


def _within_time(ctx, reach: Reachability, cands: Candidates, time_left_s: float) -> np.ndarray:
    if not np.isfinite(time_left_s):
        return np.ones(cands.n, bool)
    return _round_trip_s(ctx, reach, cands) <= time_left_s


def _round_trip_s(ctx, reach: Reachability, cands: Candidates) -> np.ndarray:
    """Least time of start -> candidate -> home: straight lines at v_max [s] (a lower bound)."""
    start, home = np.asarray(reach.start_xy_m), np.asarray(reach.home_xy_m)
    dist = (np.hypot(*(cands.start_xy_m - start).T) + cands.length_m
            + np.hypot(*(cands.end_xy_m - home).T))
    return dist / (ctx.scenario.robot.v_max_mps * ctx.conditions.duty_cycle)


def round_trip_J(reach: Reachability, cands: Candidates) -> np.ndarray:
    """Energy of start -> candidate -> home on the roadmap fields (raster terrain) [J]."""
    if cands.n == 0:
        return np.empty(0)
    ends = np.concatenate([cands.start_xy_m, cands.end_xy_m])
    pts = query_points(reach, ends, k=K_HOME)
    n = cands.n
    go = np.where(pts.valid, pts.energy_to_goal_J, np.inf)
    back = np.where(pts.valid, pts.energy_goal_to_home_J, np.inf)
    return np.minimum(go[:n], go[n:]) + np.minimum(back[:n], back[n:])


def _legs(ctx, reach: Reachability, cands: Candidates, grid, covered) -> TourSetup:
    """Dijkstra from every candidate end point over the roadmap: the leg energy/time matrices."""
    fast = reach.fast
    rm = reach.roadmap
    ends = np.concatenate([cands.start_xy_m, cands.end_xy_m])
    uniq, inverse = np.unique(np.round(ends, 9), axis=0, return_inverse=True)
    extended = add_vertices(fast, rm, uniq)
    n_old = rm.n_vertices
    point_vertex = np.r_[reach.start_index, rm.home_index, n_old + np.arange(len(uniq))]
    points_xy = extended.xy_m[point_vertex]
    graph = extended.graph()
    dist, pred = dijkstra(graph, directed=True, indices=point_vertex, return_predecessors=True)
    travel_J = dist[:, point_vertex]
    travel_s = _leg_times(ctx, fast.speed_mps, extended.xy_m, pred)[:, point_vertex]
    travel_J = np.where(np.isfinite(travel_J), travel_J, np.inf)
    n = cands.n
    entry_pt = 2 + inverse.reshape(-1)
    entry = np.stack([entry_pt[:n], entry_pt[n:]], axis=1)  # direction 0: start -> end
    exit_ = entry[:, ::-1].copy()
    e_fwd, e_rev, _, _ = fast.costs(cands.start_xy_m, cands.end_xy_m)
    lane = cands.length_m > 0
    service_J = np.stack([np.where(lane, e_fwd, 0.0), np.where(lane, e_rev, 0.0)], axis=1)
    moving = fast.speed_mps * ctx.conditions.duty_cycle
    service_s = np.repeat((cands.length_m / moving)[:, None], 2, axis=1)
    rows = np.repeat(np.arange(n), [len(c) for c in cands.cells])
    cols = np.concatenate(cands.cells) if n else np.empty(0, int)
    cells = csr_matrix((np.ones(len(cols)), (rows, cols)), shape=(n, len(grid.xy_m)))
    problem = orienteering.Orienteering(
        travel_J, travel_s, entry, exit_, service_J, service_s, cells, grid.cell_area_m2,
        start=0, end=1, budget_J=0.0, covered=covered)
    to_home = energy_field(extended, rm.home_index, towards=True)
    return TourSetup(reach, cands, grid, problem, points_xy, pred, point_vertex, extended,
                     to_home)


def _leg_times(ctx, speed_mps: float, xy: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """Mission time along every Dijkstra tree path (rows: sources) at the cruise speed [s].

    Path lengths are summed up the predecessor trees by pointer jumping (log depth steps),
    so no path is walked one vertex at a time.
    """
    rows = np.arange(pred.shape[0])[:, None]
    parent = np.where(pred < 0, np.arange(pred.shape[1])[None, :], pred)
    length = np.hypot(*(xy[None, :, :] - xy[parent]).transpose(2, 0, 1))
    for _ in range(int(np.ceil(np.log2(max(pred.shape[1], 2)))) + 1):
        length = length + length[rows, parent]
        parent = parent[rows, parent]
    return length / (speed_mps * ctx.conditions.duty_cycle)


def _probe(setup: TourSetup) -> tuple[float, float]:
    """First guesses for the budgets, from the costliest single-candidate round trip driven
    exactly: the final reserve as a share of the energy left [-] (that trip's reserve per
    joule, scaled to the whole energy left) and the factor by which the driven profile (ramps, stops) lengthens the cruise-speed
    mission time the search counts [-]. The budget loop corrects both against the exact walk.
    """
    reach = setup.reach
    res, ex = reach.reserve, reach.exact
    p = setup.problem
    trip = p.travel_J[0, p.entry[:, 0]] + p.travel_J[p.exit[:, 0], 1]
    k = int(np.argmax(np.where(np.isfinite(trip), trip, -1)))
    ids = walk_vertices(setup, [(k, 0)])
    xy = setup.roadmap_xy_m[ids]
    walk = drive(ex, xy, ex.speed_mps)
    cruise = path_energy(ex.model, ex.world, xy, ex.speed_mps, ex.conditions).duration_s
    time_factor = max(1.0, float(walk.time_s[-1]) / cruise) if cruise > 0 else 1.0
    left = reach.energy_available_J - reach.energy_used_J
    if not res.needs_variance:
        return float(res.size_J(0.0, 0.0, reach.energy_available_J)) / max(left, 1e-9), time_factor
    var = _variance(reach, walk.energy_J[-1], walk.gradient[-1])
    ratio = float(res.size_J(walk.energy_J[-1], var, reach.energy_available_J)) / max(
        walk.energy_J[-1], 1e-9)
    # reserve ~ ratio * E_tour and E_tour + reserve <= left
    return ratio / (1.0 + ratio), time_factor

