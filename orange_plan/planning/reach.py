"""Reachability: which goals can be visited with the robot still getting home .

Problem statement (kept apart from how it is solved): a goal ``g`` is feasible from a start
``s`` (home, or the robot's position after ``energy_used_J``) when a drivable path
``s -> g -> home`` exists with

    energy_used_J + E(s -> g) + E(g -> home) + reserve_J <= energy_available_J
    and  time_used_s + T(s -> g -> home) within mission.time_limit_s (mission.check_time_limit)

where ``E`` and ``T`` are the battery energy and mission time of the speed profile the robot
drives at the cruise speed (``physics.profile``: the reference-model energy plus ramps and stops) and
the reserve follows the scenario's ``mission.reserve``. How it is solved: an energy roadmap
(``roadmap``), Dijkstra fields from the start and to home, each goal joined to its nearest
roadmap vertices by collision-checked straight segments; the chosen round trip is then
re-evaluated exactly with ``path_energy`` and that exact energy and time decide feasibility. So a goal called feasible always has
a drivable round trip whose energy, as reported, fits (the roadmap may miss a cheaper one:
answers are conservative).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from orange_plan.errors import InputError, NamedInputError
from orange_plan.limits import check_roadmap_vertices
from orange_plan.mission import TimeLimitCheck, check_time_limit
from orange_plan.physics.pathcost import MAX_STEP_M, path_energy
from orange_plan.planning.paths import clean_polyline, dedupe, evaluate_path, path_gradient
from orange_plan.planning.reserve import ReserveRule, from_scenario, reserve_from
from orange_plan.planning.roadmap import (
    EdgeCostContext,
    EnergyField,
    Roadmap,
    add_vertices,
    build_roadmap,
    energy_field,
)
from orange_plan.world.rasters import TerrainRasters, build_rasters

if TYPE_CHECKING:
    from orange_plan.context import Context

K_NEAREST = 12
"""Roadmap vertices a goal is joined to (the best collision-free one is used)."""


# --- reserve ---------------------------------------------------------------------


def reserve_J(reserve, energy_available_J: float, variance_J2) -> np.ndarray:
    """Energy kept back for getting home [J] (``ReserveRule.size_J``).

    Parameters
    ----------
    reserve : a ``planning.reserve`` rule, or the scenario's ``mission.reserve``
    energy_available_J : usable battery energy E_avail [J]
    variance_J2 : predictive variance of the round trip's energy [J^2]; any shape
    """
    return from_scenario(reserve).size_J(0.0, variance_J2, energy_available_J)


RETURN_PROBABILITY_WARN = 0.9
"""Below this probability of getting home (the energy left after the planned use covering
it, under the model's predictive uncertainty, whatever the reserve rule) ``plan`` and
``reach`` warn: a fraction or fixed reserve can be too small for the model's uncertainty."""


def return_probability(slack_J, variance_J2) -> float:
    """Probability that the energy left covers the energy needed, at the worst entry [-].

    Parameters
    ----------
    slack_J : energy available minus the planned use (the reserve not counted) [J]; any shape
    variance_J2 : predictive variance of the planned use, same shape [J^2]; the use is taken
        as normal around its planned value (``ReserveRule.return_probability``)
    """
    sd = np.sqrt(np.maximum(np.asarray(variance_J2, float), 0.0))
    return float(np.min(ReserveRule.return_probability(slack_J, sd)))


def low_return_warning(what: str, probability: float | None, reserve) -> str | None:
    """One line when ``probability`` (of getting home after ``what``) is below
    ``RETURN_PROBABILITY_WARN``, else None."""
    if probability is None or probability >= RETURN_PROBABILITY_WARN:
        return None
    rule = from_scenario(reserve)
    advice = "" if rule.needs_variance else \
        "; a reserve 'confidence = p' sizes it from the model's uncertainty"
    return (f"{what}: probability of getting home {probability:.2f}, below "
            f"{RETURN_PROBABILITY_WARN:g}, under the reserve {rule.rule_text()}{advice}")


# --- set-up -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Reachability:
    """Roadmap fields for one start and home (what every goal query reads).

    Attributes
    ----------
    fast : edge costs on the terrain rasters (roadmap weights, the field image)
    exact : edge costs on exact terrain (goal connections, reported energies)
    roadmap : energy roadmap with home and start as vertices
    from_start, to_home : Dijkstra fields
    start_index : start vertex (== roadmap.home_index without ``--from``)
    energy_available_J, energy_used_J : usable battery energy, energy spent so far [J]
    reserve : the scenario's reserve rule (``planning.reserve``)
    time_limit_s : ``mission.time_limit_s`` (None: none) [s]; time_used_s : mission time so
        far [s]
    """

    fast: EdgeCostContext
    exact: EdgeCostContext
    terrain: TerrainRasters
    roadmap: Roadmap
    from_start: EnergyField
    to_home: EnergyField
    start_index: int
    energy_available_J: float
    energy_used_J: float
    reserve: ReserveRule
    time_limit_s: float | None = None
    time_used_s: float = 0.0

    def time_check(self, trip_s: float) -> TimeLimitCheck:
        """The mission time after a trip of ``trip_s`` [s] against the limit."""
        return check_time_limit(self.time_used_s + trip_s, self.time_limit_s)

    @property
    def home_xy_m(self) -> tuple[float, float]:
        return tuple(float(v) for v in self.roadmap.xy_m[self.roadmap.home_index])

    @property
    def start_xy_m(self) -> tuple[float, float]:
        return tuple(float(v) for v in self.roadmap.xy_m[self.start_index])


def cost_contexts(ctx: Context, terrain: TerrainRasters, speed_mps: float | None = None,
                  with_gradient: bool | None = None):
    """(fast, exact) edge-cost contexts of a scenario at the cruise speed.

    The cruise speed defaults to the simplified ORangE optimum ``v_opt`` (Eq. 6). The fast
    context samples terrain on the rasters once per elevation cell (or raster cell on flat
    maps): on the hilly example this changed roadmap path energies by < 0.5 % against half-cell
    steps at half the cost. The exact one uses the World and the reference-model sub-step.
    """
    sc = ctx.scenario
    if speed_mps is None:
        speed_mps = ctx.cruise_speed_mps
    if not sc.robot.v_min_mps <= speed_mps <= sc.robot.v_max_mps:
        raise InputError(f"speed {speed_mps:g} m/s is outside [v_min_mps, v_max_mps] = "
                         f"[{sc.robot.v_min_mps:g}, {sc.robot.v_max_mps:g}]")
    dem = ctx.world.map.elevation
    step = max(MAX_STEP_M, dem.cell_m if dem is not None else terrain.cell_m)
    common = (ctx.model, ctx.world)
    rest = (float(speed_mps), ctx.conditions)
    # Energy gradients (for variances) cost time; only a confidence reserve needs them,
    # unless the caller asks (the tour planner reports a return probability for any reserve).
    gradient = reserve_from(sc).needs_variance if with_gradient is None else with_gradient
    accel = sc.robot.accel_max_mps2
    return (EdgeCostContext(*common, terrain, *rest, step_m=step, with_gradient=gradient,
                            accel_max_mps2=accel),
            EdgeCostContext(*common, ctx.world, *rest, step_m=None, with_gradient=gradient,
                            accel_max_mps2=accel))


def check_start_free(world, xy) -> None:
    """Refuse a start position outside the boundary or in an obstacle / no-go zone.

    Raises
    ------
    NamedInputError
        On ``start_xy`` (each interface names it: ``--from``, the telemetry's position).
    """
    if not bool(world.is_free(*xy)):
        raise NamedInputError("start_xy", f"{{name}} ({xy[0]:g}, {xy[1]:g}) m is outside the "
                              "boundary or inside an obstacle / no-go zone")


def prepare_reach(ctx: Context, start_xy=None, energy_used_J: float = 0.0, n_vertices: int = 5000,
                  seed: int = 0, speed_mps: float | None = None,
                  terrain: TerrainRasters | None = None,
                  with_gradient: bool | None = None, time_used_s: float = 0.0) -> Reachability:
    """Build the roadmap and the two fields for reach queries.

    Parameters
    ----------
    ctx : Context (scenario, world, model)
    start_xy : robot position [m]; default home
    energy_used_J : energy already spent [J] (>= 0)
    n_vertices : roadmap size
    seed : OMPL seed
    speed_mps : cruise speed [m/s]; default v_opt
    terrain : prebuilt rasters (else built here)
    with_gradient : compute energy gradients; default only for a confidence reserve
    time_used_s : mission time already spent [s] (>= 0), counted against the time limit

    Raises
    ------
    InputError
        If ``n_vertices`` is outside the limits (``limits.check_roadmap_vertices``),
        ``energy_used_J`` is negative or exceeds the available energy, ``time_used_s`` is
        negative, or the start is not in free space.
    """
    check_roadmap_vertices(n_vertices)
    available = ctx.scenario.battery.usable_J
    if not (np.isfinite(energy_used_J) and 0.0 <= energy_used_J <= available):
        raise NamedInputError("energy_used_J", f"{{name}} = {float(energy_used_J):g} must be "
                              f"in [0, {available:.6g}] J (the usable battery energy)")
    if not (np.isfinite(time_used_s) and time_used_s >= 0.0):
        raise NamedInputError("time_used_s", f"{{name}} = {float(time_used_s):g} must be a "
                              "finite time >= 0 s")
    if start_xy is not None:
        start_xy = np.asarray(start_xy, float).reshape(2)
        check_start_free(ctx.world, start_xy)
    terrain = build_rasters(ctx.world) if terrain is None else terrain
    fast, exact = cost_contexts(ctx, terrain, speed_mps, with_gradient)
    roadmap = build_roadmap(fast, n_vertices, seed)
    start = roadmap.home_index
    if start_xy is not None and np.hypot(*(start_xy - ctx.world.home_xy_m)) > 1e-9:
        roadmap = add_vertices(fast, roadmap, start_xy[None, :])
        start = roadmap.n_vertices - 1
    from_start = energy_field(roadmap, start, towards=False)
    to_home = energy_field(roadmap, roadmap.home_index, towards=True)
    mission = ctx.scenario.mission
    return Reachability(fast, exact, terrain, roadmap, from_start, to_home, start, available,
                        float(energy_used_J), from_scenario(mission.reserve), mission.time_limit_s,
                        float(time_used_s))


# --- exact goal queries ------------------------------------------------------------------------


@dataclass(frozen=True)
class GoalResult:
    """Reach answer for one goal (energies None where there is no path).

    Attributes
    ----------
    x_m, y_m : the goal [m]
    valid : inside the boundary and outside every keep-out zone
    feasible : the round trip with its reserve fits the remaining energy
    energy_to_goal_J : start -> goal along the reported path [J]
    energy_goal_to_home_J : goal -> home (turning at the goal included) [J]
    reserve_J : reserve for this round trip [J]
    margin_J : available - used - to goal - to home - reserve [J]
    duration_s : mission time of the round trip, stops included [s]
    path_xy_m : the round trip start -> goal -> home, (n, 2) [m]
    speed_mps : cruise speed commanded at each vertex of ``path_xy_m`` [m/s]
    reason : why not valid / not feasible
    """

    x_m: float
    y_m: float
    name: str | None
    valid: bool
    feasible: bool
    energy_to_goal_J: float | None = None
    energy_goal_to_home_J: float | None = None
    reserve_J: float | None = None
    margin_J: float | None = None
    duration_s: float | None = None
    path_xy_m: np.ndarray | None = None
    speed_mps: np.ndarray | None = None
    reason: str | None = None
    return_probability: float | None = None

    def to_dict(self) -> dict:
        """JSON form; a feasible goal's route (``path_xy_m``, ``speed_mps``) as lists, to drive
        (e.g. as a ``simulate`` route CSV); an infeasible goal's path is left out."""
        d = {k: v for k, v in asdict(self).items() if k not in ("path_xy_m", "speed_mps")}
        if self.feasible:
            d["path_xy_m"] = np.asarray(self.path_xy_m, float).tolist()
            d["speed_mps"] = np.asarray(self.speed_mps, float).tolist()
        for key in ("name", "reason"):
            if d[key] is None:
                d.pop(key)
        return d


@dataclass(frozen=True)
class HomeStatus:
    """Whether the robot can get home from its start, and at what energy."""

    reachable: bool
    energy_to_home_J: float | None
    reserve_J: float | None
    margin_J: float | None
    path_xy_m: np.ndarray | None
    duration_s: float | None = None
    reason: str | None = None
    return_probability: float | None = None


def home_status(reach: Reachability) -> HomeStatus:
    """Exact energy and time of the best roadmap path start -> home and whether they fit."""
    if reach.start_index == reach.roadmap.home_index:
        xy = np.array([reach.home_xy_m, reach.home_xy_m])
        energy_J, duration_s = 0.0, 0.0
    elif not np.isfinite(reach.to_home.energy_J[reach.start_index]):
        return HomeStatus(False, None, None, None, None, reason="no path home on the roadmap")
    else:
        path = evaluate_path(reach.exact, reach.roadmap.xy_m[reach.to_home.path(
            reach.start_index)], "roadmap energy")
        xy, energy_J, duration_s = path.xy_m, path.energy_J, path.duration_s
    res, probability = _reserve_and_probability(reach, xy, energy_J)
    margin = reach.energy_available_J - reach.energy_used_J - energy_J - res
    reason = _infeasible_reason(margin, reach.time_check(duration_s), "the way home")
    return HomeStatus(reason is None, energy_J, res, margin, xy, duration_s, reason, probability)


def _infeasible_reason(margin_J: float, time: TimeLimitCheck, what: str) -> str | None:
    """None when both the energy (margin >= 0) and the time limit hold, else why not."""
    reasons = []
    if not margin_J >= 0:
        reasons.append(f"{what} and reserve exceed the remaining energy")
    if not time.within:
        reasons.append(time.reason)
    return "; ".join(reasons) or None


def _reserve_and_probability(reach: Reachability, xy, energy_J: float) -> tuple[float, float]:
    """Reserve [J] of the path ``xy`` (to home) whose exact energy is ``energy_J``, and the
    probability of getting home along it [-], both from its predictive variance."""
    var = reach.exact.model.predictive_variance_J2(path_gradient(reach.exact, xy), energy_J)
    res = float(reach.reserve.size_J(energy_J, var, reach.energy_available_J))
    slack = reach.energy_available_J - reach.energy_used_J - energy_J
    return res, return_probability(slack, var)


def invalid_reason(world, x_m: float, y_m: float) -> str | None:
    """None for a point in free space, else why not (``World.why_not_free``)."""
    return world.why_not_free(x_m, y_m)


def query_goals(reach: Reachability, goals_xy, names=None) -> list[GoalResult]:
    """Exact reach answers for a few goals (collision checks and energies on exact terrain).

    Each goal is joined to its ``K_NEAREST`` roadmap vertices (and to the start and home) by
    exactly checked straight segments; the cheapest way in and the cheapest way out are taken,
    and the whole round trip start -> goal -> home is re-evaluated with ``path_energy``.
    """
    goals = np.atleast_2d(np.asarray(goals_xy, float)).reshape(-1, 2)
    names = [None] * len(goals) if names is None else list(names)
    home = home_status(reach)
    tree = cKDTree(reach.roadmap.xy_m)
    results = []
    for (x, y), name in zip(goals.tolist(), names):
        reason = invalid_reason(reach.exact.world, x, y)
        if reason is not None:
            results.append(GoalResult(x, y, name, False, False, reason=reason))
        elif not home.reachable and home.energy_to_home_J is None:
            results.append(GoalResult(x, y, name, True, False, reason="home is unreachable "
                                      "from the start"))
        else:
            results.append(_query_one(reach, tree, x, y, name))
    return results


def _connections(reach: Reachability, tree: cKDTree, goal: np.ndarray):
    """Roadmap vertices joined to ``goal`` by an exactly checked free segment (its
    ``K_NEAREST``, the start and home), and the exact energies in and out of them [J]."""
    rm = reach.roadmap
    _, near = tree.query(goal, k=min(K_NEAREST, rm.n_vertices))
    cand = np.unique(np.r_[np.atleast_1d(near), reach.start_index, rm.home_index])
    ok = reach.exact.world.segments_free(np.repeat(goal[None], len(cand), 0), rm.xy_m[cand])
    cand = cand[ok]
    if len(cand) == 0:
        return cand, np.zeros(0), np.zeros(0)
    e_in, e_out, _, _ = reach.exact.costs(rm.xy_m[cand], np.repeat(goal[None], len(cand), 0))
    return cand, e_in, e_out


def way_home(reach: Reachability, xy, tree: cKDTree | None = None) -> np.ndarray | None:
    """The cheapest roadmap way home from a free point ``xy`` (its polyline, from ``xy``),
    or None when no exactly checked segment joins it to a vertex connected to home."""
    goal = np.asarray(xy, float).reshape(2)
    tree = tree if tree is not None else cKDTree(reach.roadmap.xy_m)
    cand, _, e_out = _connections(reach, tree, goal)
    via_out = e_out + reach.to_home.energy_J[cand]
    if not len(cand) or not np.isfinite(via_out.min()):
        return None
    b = int(cand[np.argmin(via_out)])
    return clean_polyline(dedupe(np.vstack([goal, reach.roadmap.xy_m[reach.to_home.path(b)]])))


def _query_one(reach: Reachability, tree: cKDTree, x: float, y: float, name) -> GoalResult:
    rm = reach.roadmap
    goal = np.array([x, y])
    cand, e_in, e_out = _connections(reach, tree, goal)
    if len(cand) == 0:
        return GoalResult(x, y, name, True, False, reason="no collision-free connection to the "
                          "roadmap")
    via_in = reach.from_start.energy_J[cand] + e_in
    via_out = e_out + reach.to_home.energy_J[cand]
    if not (np.isfinite(via_in.min()) and np.isfinite(via_out.min())):
        return GoalResult(x, y, name, True, False, reason="not connected to the start and home")
    a, b = int(cand[np.argmin(via_in)]), int(cand[np.argmin(via_out)])
    out = dedupe(np.vstack([rm.xy_m[reach.from_start.path(a)], goal]))
    back = np.vstack([goal, rm.xy_m[reach.to_home.path(b)]])
    trip = clean_polyline(dedupe(np.vstack([out, back])))
    c = reach.exact
    energy = path_energy(c.model, c.world, trip, c.speed_mps, c.conditions,
                         c.accel_max_mps2)
    cumulative = energy.cumulative_J
    # Turning at the goal is charged to the way back (path_energy charges a vertex's turn to
    # the segment leaving it), so the two legs add up to the round trip exactly.
    to_goal = float(cumulative[len(out) - 1])
    total = float(cumulative[-1])
    res, probability = _reserve_and_probability(reach, trip, total)
    margin = reach.energy_available_J - reach.energy_used_J - total - res
    reason = _infeasible_reason(margin, reach.time_check(energy.duration_s), "round trip")
    return GoalResult(x, y, name, True, reason is None, to_goal, total - to_goal, res, margin,
                      energy.duration_s, trip, np.full(len(trip), float(c.speed_mps)), reason,
                      probability)


# --- fast field over many points ------------------------------------------------------------


@dataclass(frozen=True)
class PointsReach:
    """Fast reach figures for many points (raster terrain, no turning at the goal).

    Attributes
    ----------
    energy_to_goal_J, energy_goal_to_home_J, reserve_J, margin_J : per point [J] (inf / nan
        where unreachable)
    valid : point in free space (raster)
    """

    energy_to_goal_J: np.ndarray
    energy_goal_to_home_J: np.ndarray
    reserve_J: np.ndarray
    margin_J: np.ndarray
    valid: np.ndarray

    @property
    def feasible(self) -> np.ndarray:
        return self.valid & (self.margin_J >= 0)


def query_points(reach: Reachability, points_xy, k: int = 8) -> PointsReach:
    """Vectorised reach figures for many points (the field image, throughput benchmarks).

    Approximate where the exact answer differs: occupancy, crr and collision tests come from
    the rasters and turning at the goal is not charged. ``query_goals`` gives exact answers.
    Points are taken in chunks of ``QUERY_CHUNK`` so memory stays flat for any count.
    """
    pts = np.atleast_2d(np.asarray(points_xy, float))
    parts = [_query_chunk(reach, chunk, k)
             for chunk in np.array_split(pts, max(1, -(-len(pts) // QUERY_CHUNK)))]
    return PointsReach(*(np.concatenate(arrays) for arrays in zip(*(
        (p.energy_to_goal_J, p.energy_goal_to_home_J, p.reserve_J, p.margin_J, p.valid)
        for p in parts))))


QUERY_CHUNK = 4096
"""Points per vectorised batch in ``query_points`` (k segments each, sub-stepped)."""


def _query_chunk(reach: Reachability, pts: np.ndarray, k: int) -> PointsReach:
    rm, fast = reach.roadmap, reach.fast
    n = len(pts)
    k = min(k, rm.n_vertices)
    valid = reach.terrain.is_free(pts[:, 0], pts[:, 1])
    _, near = cKDTree(rm.xy_m).query(pts, k=k)
    near = near.reshape(n, k)
    a = np.repeat(pts, k, axis=0)
    b = rm.xy_m[near.ravel()]
    ok = reach.terrain.segments_free(a, b).reshape(n, k) & valid[:, None]
    c_in, c_out, j_in, j_out = fast.costs(b, a)
    e_in = reach.from_start.energy_J[near] + c_in.reshape(n, k)
    e_out = c_out.reshape(n, k) + reach.to_home.energy_J[near]
    e_in, e_out = np.where(ok, e_in, np.inf), np.where(ok, e_out, np.inf)
    bi, bo = np.argmin(e_in, axis=1), np.argmin(e_out, axis=1)
    rows = np.arange(n)
    to_goal, to_home = e_in[rows, bi], e_out[rows, bo]
    var = np.zeros(n)
    if reach.reserve.needs_variance:
        kk = j_in.shape[1]
        g = (reach.from_start.gradient[near[rows, bi]] + j_in.reshape(n, k, kk)[rows, bi]
             + j_out.reshape(n, k, kk)[rows, bo] + reach.to_home.gradient[near[rows, bo]])
        with np.errstate(invalid="ignore"):  # unreachable points: inf energy, nan variance
            var = fast.model.predictive_variance_J2(g, to_goal + to_home)
    res = reach.reserve.size_J(to_goal + to_home, var, reach.energy_available_J)
    with np.errstate(invalid="ignore"):
        margin = reach.energy_available_J - reach.energy_used_J - to_goal - to_home - res
    return PointsReach(to_goal, to_home, res, margin, valid)
