"""A tour's walk: its roadmap vertices, speeds and exact re-evaluation, and the plan summary.

A walk is the closed polyline ``start -> candidates -> home`` on the extended roadmap of a
``tour.TourSetup`` (``walk_vertices``; BIT* may replace its costliest legs, ``refine_legs``).
``evaluate_walk`` gives it speeds (the CasADi optimiser, capped at the sensing speed) and
re-evaluates it exactly: the energy drawn at every vertex as driven (``drive``: ramps, stops
and the final duty-cycle wait), the return home from every vertex on the roadmap
(``home_legs``), the reserve and the margin ``E_avail - E_used - E_home - reserve``. The
tour search (``tour.search_tour``) and the sweep plans (``sweep_plan``) keep a walk only when
every margin is >= 0; ``_finish`` completes its summary (docs/json.md).
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field, replace

import numpy as np

from orange_plan.errors import InputError, PlanningError
from orange_plan.physics.pathcost import path_energy, segments_energy_jacobian, subdivide
from orange_plan.planning import orienteering
from orange_plan.planning.coverage import Candidates, footprint
from orange_plan.planning.paths import clean_polyline, evaluate_path
from orange_plan.planning.plan import Plan, StartState
from orange_plan.planning.reach import Reachability, return_probability
from orange_plan.planning.returns import DrivenReturns
from orange_plan.planning.roadmap import EnergyField, Roadmap, add_vertices, energy_field


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


BITSTAR_S = 0.5
"""BIT* budget per refined leg [s]."""
BITSTAR_LEGS = 3
"""Costliest legs offered to BIT* per tour."""
def _per_metre(model, ctx, speed_mps: float | None = None) -> float:
    """Battery energy per metre of a model on flat default ground, at the cruise speed unless
    ``speed_mps`` is given [J/m]."""
    from orange_plan.physics.range import flat_energy_per_m_J

    speed = ctx.cruise_speed_mps if speed_mps is None else speed_mps
    return float(flat_energy_per_m_J(model, speed, ctx.world.default_crr,
                                     ctx.conditions.sensor_rate_Hz, ctx.conditions.duty_cycle,
                                     ctx.conditions.elapsed_s))


def _time_left_s(ctx, start: StartState) -> float:
    limit = ctx.scenario.mission.time_limit_s
    if limit is None:
        return np.inf
    left = limit - start.time_s
    if left <= 0:
        raise InputError(f"mission.time_limit_s = {limit:g} s is already spent "
                         f"(time so far {start.time_s:g} s)")
    return float(left)


def drivable_m(ctx, reach: Reachability, time_left_s: float) -> float:
    """Farthest the robot could drive: the energy left over the least energy per metre, or
    v_max for the time left, whichever is shorter [m] (an upper bound for any tour)."""
    left = reach.energy_available_J - reach.energy_used_J
    dist = left / min_energy_per_m(ctx)
    if np.isfinite(time_left_s):
        dist = min(dist, ctx.scenario.robot.v_max_mps * ctx.conditions.duty_cycle * time_left_s)
    return float(dist)


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
    """Covered area, waypoints and the plan summary (docs/json.md)."""
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
    coefficient at the best speed (Eq. 6's denominator) [J/m] (the coverage bound, docs/json.md)."""
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
