"""Exploration tours: the most area sensed on one discharge, with the way home always kept.

Problem statement (kept apart from how it is solved): from a start state (position ``s``,
energy already used ``E_0``, time ``t_0``, area already sensed) find a drivable closed walk
``s -> ... -> home`` with per-segment speeds that

    maximises   the area sensed: the free workspace within ``sensor_radius_m`` of the walk
    subject to  at every vertex v of the walk
                E_0 + E(s -> v) + E_home(v) + reserve(v) <= E_avail        (homing constraint)
                and the walk ends at home with  t_0 + duration <= time_limit_s

where ``E`` is the battery energy of SPEC §7 at the planned speeds, ``E_home(v)`` the energy
of the best roadmap return from ``v`` at the cruise speed and ``reserve(v)`` the scenario's
reserve rule for the energy spent so far plus the return (``confidence = p``: from the model's
predictive variance of that energy, so the return succeeds with probability >= p).

How it is solved: an energy roadmap (``planning.roadmap``) gives minimum-energy legs between
coverage candidates (sweep-lane pieces and viewpoints, ``planning.coverage``); an orienteering
heuristic (``planning.orienteering``: greedy insertion by new area per joule, 2-opt and or-opt)
chooses and orders them under an energy budget; the CasADi speed optimiser
(``planning.speed``) then chooses a speed per segment (energy-optimal, capped on sweep lanes so
the sensor keeps up); and the result is re-evaluated: energies along the walk with
``path_energy`` at those speeds, the return from every vertex on the roadmap, the reserve from
the model. If any vertex breaks the homing constraint the budget is lowered by the deficit and
the tour re-chosen. Beside it, complete sweeps (``planning.sweeps``) are scored under the
closed-loop homing rule; the best one's prefix is checked the same way (``sweep_tour``) and
the rest kept as the plan's continuation; ``plan_tour`` keeps whichever answer is expected to
sense more in closed loop. Why the answer is safe: feasibility is decided on the re-evaluated
walk, at every vertex, not on the heuristic's estimates; a plan is only returned when every
margin is >= 0 (a continuation is flown only under the live check).
"""

from __future__ import annotations

import contextlib
import functools
import math
import time as _time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from orange_plan.errors import InputError, PlanningError
from orange_plan.limits import check_roadmap_vertices
from orange_plan.mission import check_time_limit
from orange_plan.physics.pathcost import path_energy, segments_energy_jacobian, subdivide
from orange_plan.planning import orienteering
from orange_plan.planning.coverage import (
    DEFAULT_MAX_LANE_FRACTION,
    Candidates,
    check_sensor_radius,
    coverage_candidates,
    coverage_grid,
    footprint,
)
from orange_plan.planning.paths import clean_polyline, cut_path, evaluate_path
from orange_plan.planning.plan import Plan, StartState
from orange_plan.planning.reach import (
    Reachability,
    check_start_free,
    home_status,
    prepare_reach,
    query_points,
    return_probability,
)
from orange_plan.planning.reserve import closed_loop_return_spread, reserve_from
from orange_plan.planning.returns import DrivenReturns
from orange_plan.planning.roadmap import EnergyField, Roadmap, add_vertices, energy_field

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
BITSTAR_S = 0.5
"""BIT* budget per refined leg [s]."""
BITSTAR_LEGS = 3
"""Costliest legs offered to BIT* per tour."""
K_HOME = 8
"""Roadmap vertices each walk vertex is joined to for its return home."""


@dataclass(frozen=True)
class TourSetup:
    """Everything the tour search reads: roadmap fields, candidates, and their leg matrix."""

    reach: Reachability
    candidates: Candidates
    grid: object
    problem: orienteering.Orienteering
    points_xy_m: np.ndarray  # (P, 2): 0 = start, 1 = home, then candidate end points
    predecessors: np.ndarray  # (P, V) Dijkstra predecessors on the extended roadmap
    point_vertex: np.ndarray  # (P,) roadmap vertex of each point
    roadmap: Roadmap  # the reach roadmap extended by the candidates' end points
    to_home: EnergyField  # energy to home from every vertex of the extended roadmap
    # (a warm setup's has no gradient columns: ``warm_setup``)
    # the returns' drives, shared by the warm setups made from this one (``returns``)
    returns: DrivenReturns = field(default_factory=DrivenReturns, compare=False, repr=False)

    @property
    def roadmap_xy_m(self) -> np.ndarray:
        return self.roadmap.xy_m


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


def sweep_tour(ctx, setup: TourSetup, start: StartState, *, t0: float,
               optimise_speed: bool = True, baseline: bool = True) -> Plan | None:
    """The best complete sweep (``planning.sweeps``) as a plan, or None.

    The sweep is chosen by what it senses before the closed-loop rule turns it home; its
    prefix up to the open-loop turn is then checked exactly like any tour (``evaluate_walk``:
    energies, returns and reserves at every vertex), its length bisected until every margin
    is >= 0 with little slack (``_guaranteed_prefix``), and the rest of the sweep becomes
    the plan's ``continuation_xy_m``: the route a robot that measures its energy flies on,
    turning home on the live check. ``baseline``: the lawnmower's own route
    (``lawnmower.plan_lawnmower``) is among the sweeps scored, so the plan senses at least
    as much as the lawnmower under the same rule. None for a start away from home or with
    area already sensed (a replan), or when no sweep keeps the way home.
    """
    from orange_plan.planning.homepaths import HomePaths
    from orange_plan.planning.lawnmower import Detours, SweepLanes, plan_lawnmower
    from orange_plan.planning.sweeps import best_sweep, score_route, score_step_m

    reach = setup.reach
    home_xy = np.asarray(reach.home_xy_m, float)
    at_home = start.xy_m is None or np.hypot(*(np.asarray(start.xy_m, float) - home_xy)) < 1e-6
    if not at_home or start.covered is not None:
        return None
    e_left = reach.energy_available_J - reach.energy_used_J
    time_left = _time_left_s(ctx, start)
    home = HomePaths(reach).calibrate(functools.partial(driven_energy_J, reach.exact))
    rm = reach.roadmap
    detours = Detours(ctx.world, rm.xy_m, rm.src, rm.dst)
    lanes = SweepLanes(ctx.world, setup.grid, ctx.scenario.mission.sensor_radius_m)
    baseline_xy = None
    # no lawnmower joins up on some roadmaps: the other sweeps still may
    with contextlib.suppress(PlanningError):
        baseline_xy = plan_lawnmower(ctx, reach, lanes=lanes).xy_m if baseline else None
    longest = 1.05 * drivable_m(ctx, reach, time_left)
    # chosen under the rule that flies it: a closed loop keeps for its way home the floor of
    # the a-priori discrepancy (``RETURN_SPREAD_FLOOR``), not all of it; scored with all of
    # it, sweeps whose returns are short look better than they fly
    flown = replace(ctx, model=ctx.model.with_discrepancy(closed_loop_return_spread(ctx.model)))
    sweep = best_sweep(flown, reach, home, setup.grid, detours, baseline_xy, e_left, time_left,
                       longest, lanes=lanes)
    if sweep is None:
        return None
    # the guaranteed prefix is sought from its turn points on the scenario's model; the
    # closed loop's own (the summary's expectation) are the ones it was chosen by
    opened = score_route(ctx, reach.fast, home, setup.grid, sweep.xy_m, e_left, time_left,
                         score_step_m(ctx), longest, reach.reserve)
    checked = _guaranteed_prefix(ctx, setup, start, sweep.xy_m, opened.open_s_m,
                                 opened.closed_s_m, time_left, optimise_speed)
    if checked is None:
        return None
    walk_setup, plan, variance, cut_m = checked
    plan = _finish(ctx, walk_setup, plan, plan.xy_m[1:-1], variance, start, t0)
    closed_m2 = max(sweep.score.closed_m2, plan.summary["coverage_m2"])
    summary = {**plan.summary,
               "pattern": sweep.pattern,
               "sweeps_scored": sweep.tried,
               "guaranteed_length_m": cut_m,
               "closed_loop_turn_m": max(sweep.score.closed_s_m, cut_m),
               "closed_loop_coverage_m2": closed_m2,
               "closed_loop_speed_mps": float(reach.exact.speed_mps),
               "sweep_length_m": sweep.score.length_m}
    return replace(plan, summary=summary, continuation_xy_m=route_after(sweep.xy_m, cut_m))


PREFIX_TRIES = 9
"""Exact checks of a sweep prefix's length (a bisection started at the scored guess)."""


def _guaranteed_prefix(ctx, setup: TourSetup, start: StartState, route, guess_m: float,
                       upper_m: float, time_left: float, optimise_speed: bool):
    """The longest prefix of ``route`` whose walk home keeps every margin >= 0 and the time
    limit, found by bisection on the exact check between 0 and ``upper_m`` (the closed-loop
    turn: no open-loop prefix goes farther), starting at ``guess_m``: (walk setup, plan,
    variance, length [m]) or None when no prefix fits."""
    per_m = _per_metre(ctx.model, ctx)
    lo, hi, best = 0.0, max(upper_m, guess_m), None
    cut_m = guess_m if 0 < guess_m < hi else 0.5 * hi
    for _ in range(PREFIX_TRIES):
        if cut_m <= 0 or hi - lo <= 0.01 * hi:
            break
        walk = _walk_along(setup, cut_path(route, cut_m))
        fits = False
        if walk is not None:
            walk_setup, ids = walk
            plan, variance = evaluate_walk(ctx, walk_setup, ids, start, optimise_speed)
            slack = float(plan.margin_J.min())
            fits = slack >= 0 and float(plan.t_s[-1]) - start.time_s <= time_left
        if fits:
            lo, best = cut_m, (walk_setup, plan, variance, cut_m)
            if slack < 1e-3 * per_m * max(cut_m, 1.0):
                break
            cut_m = min(0.5 * (lo + hi), cut_m + slack / per_m)
        else:
            hi = cut_m
            cut_m = 0.5 * (lo + hi)
    return best


def _walk_along(setup: TourSetup, prefix_xy):
    """``prefix_xy`` (from home) as roadmap vertices, then the roadmap's way home:
    (setup with the extended roadmap and to-home field, walk vertex ids), or None when a
    prefix vertex cannot be joined to the roadmap."""
    pts = np.asarray(prefix_xy, float)[1:]
    if len(pts) == 0:
        return None
    roadmap = add_vertices(setup.reach.fast, setup.roadmap, pts)
    new = setup.roadmap.n_vertices + np.arange(len(pts))
    to_home = energy_field(roadmap, roadmap.home_index, towards=True)
    if not np.all(np.isfinite(to_home.energy_J[new])):
        return None
    back = to_home.path(int(new[-1]))
    ids = np.r_[roadmap.home_index, new, back[1:]].astype(int)
    return replace(setup, roadmap=roadmap, to_home=to_home), ids


def route_after(route, s_m: float) -> np.ndarray:
    """The part of a polyline after arclength ``s_m`` (the cut point first) [m]."""
    route = np.asarray(route, float)
    total = float(np.sum(np.hypot(*np.diff(route, axis=0).T)))
    return cut_path(route[::-1], max(total - s_m, 0.0))[::-1]


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


def _per_metre(model, ctx, speed_mps: float | None = None) -> float:
    """Battery energy per metre of a model on flat default ground, at the cruise speed unless
    ``speed_mps`` is given [J/m]."""
    from orange_plan.physics.range import flat_energy_per_m_J

    speed = ctx.cruise_speed_mps if speed_mps is None else speed_mps
    return float(flat_energy_per_m_J(model, speed, ctx.world.default_crr,
                                     ctx.conditions.sensor_rate_Hz, ctx.conditions.duty_cycle))


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


def _time_left_s(ctx, start: StartState) -> float:
    limit = ctx.scenario.mission.time_limit_s
    if limit is None:
        return np.inf
    left = limit - start.time_s
    if left <= 0:
        raise InputError(f"mission.time_limit_s = {limit:g} s is already spent "
                         f"(time so far {start.time_s:g} s)")
    return float(left)


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


def drivable_m(ctx, reach: Reachability, time_left_s: float) -> float:
    """Farthest the robot could drive: the energy left over the least energy per metre, or
    v_max for the time left, whichever is shorter [m] (an upper bound for any tour)."""
    left = reach.energy_available_J - reach.energy_used_J
    dist = left / min_energy_per_m(ctx)
    if np.isfinite(time_left_s):
        dist = min(dist, ctx.scenario.robot.v_max_mps * ctx.conditions.duty_cycle * time_left_s)
    return float(dist)


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


# --- the walk: polyline, speeds, re-evaluation ---------------------------------------------


def walk_vertices(setup: TourSetup, nodes) -> np.ndarray:
    """Roadmap vertices of the walk start -> candidates (in order and direction) -> home.

    Every vertex of a walk is a vertex of the extended roadmap (legs follow roadmap edges,
    lanes join two candidate end points), so its return home is read off the to-home field.
    """
    return _join(_walk_parts(setup, nodes))


def _walk_parts(setup: TourSetup, nodes) -> list[np.ndarray]:
    """The walk as alternating vertex arrays: [start], leg, [exit], leg, ..., leg to home."""
    p = setup.problem
    parts = [setup.point_vertex[:1]]
    at = p.start
    for i, o in nodes:
        parts.append(_leg(setup, at, int(p.entry[i, o])))
        parts.append(setup.point_vertex[[p.exit[i, o]]])
        at = int(p.exit[i, o])
    parts.append(_leg(setup, at, p.end))
    return parts


def _join(parts) -> np.ndarray:
    ids = np.concatenate(parts).astype(int)
    ids = ids[np.r_[True, ids[1:] != ids[:-1]]]
    return ids if len(ids) >= 2 else np.r_[ids, ids]


def refine_legs(setup: TourSetup, nodes, seconds: float = BITSTAR_S,
                max_legs: int = BITSTAR_LEGS, seed: int = 0):
    """Replace the costliest legs by BIT*'s paths where those are cheaper ("where it pays").

    The roadmap legs are already near the grid optimum (``bench reach``), so only the
    ``max_legs`` legs of highest exact energy get ``seconds`` of BIT* each; a BIT* path is
    kept when its exact energy is lower by more than 0.1 %. Its vertices join the roadmap
    (collision-checked edges) and the to-home field is recomputed, so the homing check reads
    every vertex's return as before. Returns (setup, walk vertex ids, legs improved).
    """
    from orange_plan.planning.paths import bitstar_path

    parts = _walk_parts(setup, nodes)
    if seconds <= 0 or max_legs <= 0:
        return setup, _join(parts), 0
    ex, xy = setup.reach.exact, setup.roadmap_xy_m
    legs = [k for k in range(1, len(parts), 2) if len(parts[k]) >= 2]
    energy = {k: evaluate_path(ex, xy[parts[k]], "roadmap leg").energy_J for k in legs}
    costly = sorted(legs, key=lambda k: -energy[k])[:max_legs]
    new_xy, replaced = [], {}
    for k in costly:
        a, b = xy[parts[k][0]], xy[parts[k][-1]]
        bit = bitstar_path(setup.reach.fast, ex, a, b, seconds, seed)
        if bit is None or bit.energy_J >= energy[k] * (1 - 1e-3) or len(bit.xy_m) < 3:
            continue
        inner = bit.xy_m[1:-1]
        first = setup.roadmap.n_vertices + sum(len(v) for v in new_xy)
        replaced[k] = np.r_[parts[k][0], first + np.arange(len(inner)), parts[k][-1]]
        new_xy.append(inner)
    if not replaced:
        return setup, _join(parts), 0
    roadmap = add_vertices(setup.reach.fast, setup.roadmap, np.concatenate(new_xy))
    to_home = energy_field(roadmap, setup.roadmap.home_index, towards=True)
    new_ids = np.concatenate(list(replaced.values()))
    if not np.all(np.isfinite(to_home.energy_J[new_ids])):
        return setup, _join(parts), 0  # a BIT* vertex the roadmap cannot join: keep the legs
    parts = [replaced.get(k, part) for k, part in enumerate(parts)]
    return replace(setup, roadmap=roadmap, to_home=to_home), _join(parts), len(replaced)


def _leg(setup: TourSetup, a: int, b: int) -> np.ndarray:
    """Roadmap vertex ids of the leg from point a to point b (both ends included)."""
    pred = setup.predecessors[a]
    target = int(setup.point_vertex[b])
    source = int(setup.point_vertex[a])
    seq = [target]
    while seq[-1] != source:
        nxt = int(pred[seq[-1]])
        if nxt < 0:
            raise PlanningError(f"no roadmap leg between tour points {a} and {b}")
        seq.append(nxt)
    return np.array(seq[::-1])


def sensing_speed_mps(ctx) -> float:
    """Fastest speed at which the sensor still sees every point of a sweep lane [m/s].

    One frame per footprint radius travelled: ``sensor_radius_m * sensor_rate_Hz``; with no
    sensor rate the cap is the robot's ``v_max_mps``.
    """
    sc = ctx.scenario
    rate = sc.ancillary.sensor_rate_Hz
    cap = sc.mission.sensor_radius_m * rate if rate > 0 else sc.robot.v_max_mps
    return float(np.clip(cap, sc.robot.v_min_mps, sc.robot.v_max_mps))


def evaluate_walk(ctx, setup: TourSetup, ids: np.ndarray, start: StartState,
                  optimise_speed: bool = True,
                  time_factor: float = 1.0) -> tuple[Plan, np.ndarray]:
    """Speeds for a walk and its exact per-vertex figures (energies, return, reserve, margin).

    Returns the Plan (its summary completed by ``_finish``) and the predictive variance of
    the energy still needed at each vertex [J^2] (for the return probability).
    """
    reach = setup.reach
    xy = setup.roadmap_xy_m[ids]
    speeds = _speeds(ctx, xy, start, time_factor) if optimise_speed else None
    if speeds is None:
        speeds = np.full(len(xy) - 1, reach.exact.speed_mps)
    walk = drive(reach.exact, xy, speeds)
    used = reach.energy_used_J + walk.energy_J
    home = home_legs(setup, ids)
    needed = walk.energy_J + home.energy_J  # what must still come out of the battery
    gradient = walk.gradient + home.gradient
    var = _variance(reach, needed, gradient)
    res = reach.reserve.size_J(needed, var, reach.energy_available_J)
    margin = reach.energy_available_J - used - home.energy_J - res
    plan = Plan(xy, start.time_s + walk.time_s, np.r_[speeds, speeds[-1]], used, home.energy_J,
                res, margin, np.empty((0, 2)), None, {})
    return plan, _variance(reach, needed, gradient, always=True)


def _speeds(ctx, xy: np.ndarray, start: StartState, time_factor: float = 1.0):
    """Per-segment speeds from the CasADi optimiser, None when it cannot help.

    The optimiser sees constant-speed pieces; the time the robot really takes (ramps and
    stops) is ``time_factor`` longer (``_probe``), so its limit is tightened by that factor
    and the exact check of ``evaluate_walk`` (which drives the profile anyway) decides.
    """
    from orange_plan.planning.speed import SpeedSolver, cut_path, speed_problem

    n_seg = len(xy) - 1
    pieces = cut_path(ctx.world, xy, n_seg)
    limit = ctx.scenario.mission.time_limit_s
    limit = None if limit is None else (limit - start.time_s) / time_factor
    try:
        problem = speed_problem(ctx, pieces, time_limit_s=limit)
        problem = replace(problem, piece_v_max_mps=_lane_caps(ctx, xy))
        profile = SpeedSolver(ctx.model).solve(problem)
    except (InputError, PlanningError):
        return None
    return np.asarray(profile.speed_mps, float)


def _lane_caps(ctx, xy: np.ndarray) -> np.ndarray:
    """Per-segment speed cap: the sensing speed everywhere (the whole walk senses) [m/s]."""
    return np.full(len(xy) - 1, sensing_speed_mps(ctx))


@dataclass(frozen=True)
class Driven:
    """Energy drawn along a driven path, at its vertices.

    Attributes
    ----------
    energy_J : cumulative battery energy on reaching each vertex (the last: at rest at the
        end, the final duty-cycle wait included) [J]
    time_s : mission time at each vertex [s]
    gradient : d energy_J / d theta at each vertex, shape (n, k)
    """

    energy_J: np.ndarray
    time_s: np.ndarray
    gradient: np.ndarray


def drive(cost, xy, speed_mps) -> Driven:
    """Energy, time and gradient of a polyline as ``path_energy`` / ``path_gradient`` give
    them (the driven speed profile when ``cost`` carries an acceleration limit), from one
    drive: both come from the same samples, so they cost one profile instead of two."""
    from orange_plan.physics.profile import profile_energy_and_gradient

    xy = np.asarray(xy, float)
    speed = np.broadcast_to(np.asarray(speed_mps, float), (len(xy) - 1,))
    model, world = cost.model, cost.world
    steps = subdivide(world, xy[:-1], xy[1:])
    if cost.accel_max_mps2 is None or not np.any(steps.horiz_m > 0):
        energy = path_energy(model, world, xy, speed, cost.conditions)
        jac = segments_energy_jacobian(model, world, steps, speed, cost.conditions)
        grad = np.vstack([np.zeros((1, jac.shape[1])), np.cumsum(jac, axis=0)])
        return Driven(energy.cumulative_J, energy.cumulative_time_s, grad)
    drawn, cum_g = profile_energy_and_gradient(model, steps, steps.per_step(speed),
                                               cost.accel_max_mps2, cost.conditions)
    vertex_s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]
    energy, time = drawn.at_arclength(vertex_s)
    grad = drawn.drawn_before(cum_g, vertex_s)
    # the last vertex: at rest at the end, the final duty-cycle wait included
    energy[-1], grad[-1], time[-1] = drawn.total_J, cum_g[-1], drawn.duration_s
    return Driven(energy, time.astype(float), grad)


def driven_energy_J(cost, xy) -> float:
    """Battery energy of driving a polyline at ``cost``'s speed from rest to rest, the final
    duty-cycle wait included (``drive``) [J]."""
    return float(drive(cost, xy, cost.speed_mps).energy_J[-1])


def home_legs(setup: TourSetup, ids: np.ndarray) -> Driven:
    """Energy [J] and gradient of the return home from each walk vertex (time: unused, 0).

    The return is the minimum-energy path of the roadmap's to-home field from that vertex,
    re-evaluated exactly like the walk itself (exact terrain, the driven speed profile from
    rest to rest at the cruise speed): the field's raster figures only choose the path, so
    the margin at every vertex is that of a return the robot can really drive.
    """
    field, ex = setup.to_home, setup.reach.exact
    k = len(ex.model.theta)
    ids = np.asarray(ids, int)
    # a walk passes some vertices more than once (lane ends, shared transits): one return each
    unique, first, back_to = np.unique(ids, return_index=True, return_inverse=True)
    energy, grad = np.zeros(len(unique)), np.zeros((len(unique), k))
    rows, paths = [], []
    for n, v in enumerate(unique):
        if v == setup.roadmap.home_index:
            continue
        if not np.isfinite(field.energy_J[v]):
            raise PlanningError(f"walk vertex {int(first[n])} at "
                                f"{tuple(np.round(setup.roadmap_xy_m[v], 2))} m has no roadmap "
                                "return home")
        xy = clean_polyline(setup.roadmap_xy_m[field.path(v)])
        if np.hypot(*(xy[-1] - xy[0])) > 1e-9 or len(xy) > 2:  # a vertex on home costs 0
            rows.append(n)
            paths.append(xy)
    if not rows:
        return Driven(energy[back_to], np.zeros(len(ids)), grad[back_to])
    if ex.accel_max_mps2 is None:
        for n, xy in zip(rows, paths):
            back = drive(ex, xy, ex.speed_mps)
            energy[n], grad[n] = back.energy_J[-1], back.gradient[-1]
        return Driven(energy[back_to], np.zeros(len(ids)), grad[back_to])
    # The returns' motion does not depend on the model: kept across replans (``returns``).
    from orange_plan.physics.profile import driven_energies_and_gradients

    steps, kins = setup.returns.driven(ex, paths)
    energy[rows], grad[rows] = driven_energies_and_gradients(ex.model, steps, kins,
                                                             ex.conditions)
    return Driven(energy[back_to], np.zeros(len(ids)), grad[back_to])


def _variance(reach: Reachability, energy_J, gradient, always: bool = False) -> np.ndarray:
    """Predictive variance of an energy still to be drawn [J^2] (zero unless the reserve is
    a confidence, or ``always``): the coefficients' covariance along ``gradient`` plus the
    run-to-run discrepancy (``EnergyModel.predictive_variance_J2``, as every reserve)."""
    energy = np.asarray(energy_J, float)
    if not reach.reserve.needs_variance and not always:
        return np.zeros(energy.shape)
    var = reach.exact.model.predictive_variance_J2(gradient, energy)
    return np.asarray(var, float).reshape(energy.shape)


# --- summary -------------------------------------------------------------------------------


def _finish(ctx, setup: TourSetup, plan: Plan, waypoints, variance, start: StartState,
            t0: float) -> Plan:
    """Covered area, waypoints and the SPEC §4 summary."""
    reach = setup.reach
    world = ctx.world
    r = ctx.scenario.mission.sensor_radius_m
    covered = footprint(world, plan.xy_m, r)
    if start.covered is not None:
        covered = covered.union(start.covered)
    free_area = setup.grid.free_area_m2
    final_reserve = float(plan.reserve_J[-1])
    motion = max(reach.energy_available_J - reach.energy_used_J - final_reserve, 0.0)
    reach_m = motion / min_energy_per_m(ctx)
    if ctx.scenario.mission.time_limit_s is not None:  # and never faster than v_max
        reach_m = min(reach_m, drivable_m(ctx, reach, _time_left_s(ctx, start)))
    bound = min(free_area, 2 * r * reach_m + np.pi * r**2)
    waypoints = np.asarray(waypoints, float).reshape(-1, 2)
    summary = {
        "energy_available_J": reach.energy_available_J,
        "energy_planned_J": float(plan.energy_used_J[-1] - reach.energy_used_J),
        "reserve_J": final_reserve,
        "coverage_m2": float(covered.area),
        "coverage_fraction": float(covered.area / free_area) if free_area > 0 else 0.0,
        "coverage_bound_m2": float(bound),
        "duration_s": float(plan.t_s[-1] - start.time_s),
        "return_probability": plan_return_probability(setup.reach, plan, variance),
        "planner_seconds": _time.perf_counter() - t0,
        "energy_used_start_J": reach.energy_used_J,
        "candidates_visited": len(waypoints),
        "min_margin_J": float(plan.margin_J.min()),
        "reserve_rule": reach.reserve.rule_text(),
    }
    return replace(plan, waypoints_xy_m=waypoints, covered=covered, summary=summary)


def min_energy_per_m(ctx) -> float:
    """Least battery energy per metre anywhere on the map: flat ground of the lowest rolling
    coefficient at the best speed (Eq. 6's denominator) [J/m] (coverage bound, SPEC §4)."""
    from orange_plan.physics.range import simplified_range

    crr = min([ctx.world.default_crr, *(s.crr for s in ctx.world.map.surfaces)])
    return simplified_range(ctx.scenario, ctx.model, crr).energy_per_m_J


def plan_return_probability(reach: Reachability, plan: Plan, variance_J2) -> float:
    """Probability of getting home from the worst vertex of the plan [-].

    The energy still needed at a vertex (used so far + return) is taken as normal around its
    planned value with its predictive variance ``variance_J2``, whatever the reserve rule.
    """
    return return_probability(
        reach.energy_available_J - plan.energy_used_J - plan.energy_to_home_J, variance_J2)
