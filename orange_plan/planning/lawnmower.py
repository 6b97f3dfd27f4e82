"""Boustrophedon ("lawnmower") coverage path: the usual-practice baseline of ``bench plan``.

Lanes at most ``2 r`` apart (r = ``mission.sensor_radius_m``; the lanes of
``planning.coverage.coverage_candidates``) sweep the free workspace at one angle, driven back
and forth lane by lane; where an obstacle splits a lane, its pieces are driven in the direction
of travel. Consecutive pieces are joined by a straight segment when it is collision-free, else
by the shortest path over the energy roadmap's geometry (``planning.roadmap``); the path starts
and ends at home. The sweep angle is the one that would cover most before the robot has to
turn home on the planning model (``best_energy_sweep_angle_deg``). Sensed area:
``planning.coverage.footprint``.

The path knows nothing about energy beyond the choice of angle: when to stop and go home is
decided in flight by a return rule (``bench.px4_rtl``), as an autopilot would.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import shapely
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from orange_plan.errors import PlanningError
from orange_plan.physics.pathcost import heading_changes_rad, segments_energy, subdivide
from orange_plan.planning.paths import clean_polyline, distinct_vertices
from orange_plan.planning.reserve import reserve_from

DEFAULT_ANGLES_DEG = tuple(float(a) for a in range(0, 360, 10))
"""Sweep angles tried by ``best_energy_sweep_angle_deg`` [deg]; the best one is refined by
+-5 deg. Angles a and a + 180 have the same lanes, swept from opposite sides."""

K_ATTACH = 12
"""Roadmap vertices a detour's end points are joined to (collision-checked)."""


@dataclass(frozen=True)
class Lawnmower:
    """A lawnmower path from home back home.

    Attributes
    ----------
    xy_m : vertices, shape (n, 2), first and last = home [m]
    angle_deg : lane direction, counter-clockwise from east [deg]; >= 180: the lanes of
        ``angle_deg - 180`` swept from the other side (``sweep_lanes``)
    spacing_m : largest distance between lanes, 2 x the sensor radius [m]
    speed_mps : commanded speed on every segment (the cruise speed) [m/s]
    n_lanes : lane pieces driven
    n_detours : joins that needed a roadmap path
    planner_seconds : wall-clock time to plan it, angle search included [s]
    """

    xy_m: np.ndarray
    angle_deg: float
    spacing_m: float
    speed_mps: float
    n_lanes: int
    n_detours: int
    planner_seconds: float

    @property
    def length_m(self) -> float:
        """Horizontal length [m]."""
        return float(np.sum(np.hypot(*np.diff(self.xy_m, axis=0).T)))


# --- geometry -------------------------------------------------------------------------------

LONG_LANE_M = 1e9
"""``max_lane_m`` passed to ``coverage_candidates``: lanes are not chopped here [m]."""


def sweep_lanes(world, grid, sensor_radius_m: float, angle_deg: float):
    """Lane pieces at ``angle_deg``, grouped by lane, from ``planning.coverage``.

    Parameters
    ----------
    world : World
    grid : ``coverage.coverage_grid(world, r)``
    sensor_radius_m : footprint radius r [m] (lanes at most 2 r apart)
    angle_deg : lane direction, counter-clockwise from east [deg]; in [0, 180) the lanes are
        swept in the direction of the normal ``n = (-sin a, cos a)``, in [180, 360) the same
        lanes against it (starting from the other side)

    Returns
    -------
    list of lanes in sweep order; each lane a list of pieces (2, 2) [m], ordered and oriented
    along the lane direction ``u = (cos a, sin a)`` (a taken modulo 180).

    Notes
    -----
    The lanes are ``coverage_candidates``' (kinds "lane", not chopped): r in from the free
    space's extreme edges, at most 2 r apart, clipped to the free space eroded by 0.02 r and
    split by keep-out zones. Pieces of one lane share their normal offset ``p . n``.
    """
    from orange_plan.planning.coverage import coverage_candidates

    cand = coverage_candidates(world, grid, sensor_radius_m, angle_deg, kinds=("lane",),
                               max_lane_m=LONG_LANE_M)
    a = math.radians(cand.sweep_angle_deg)
    u, nrm = np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])
    start, end = cand.start_xy_m, cand.end_xy_m
    flip = (end - start) @ u < 0
    start, end = np.where(flip[:, None], end, start), np.where(flip[:, None], start, end)
    offset = np.round(start @ nrm, 6)
    lanes = []
    for off in np.unique(offset):
        k = np.flatnonzero(offset == off)
        k = k[np.argsort(start[k] @ u)]
        lanes.append([np.array([start[i], end[i]]) for i in k])
    return lanes[::-1] if float(angle_deg) % 360.0 >= 180.0 else lanes


class SweepLanes:
    """``sweep_lanes`` of one world, coverage grid and sensor radius, each angle's lanes
    computed once: the lawnmower's angle search and the planner's sweeps ask for the same
    angles, and a and a + 180 deg share their lanes (swept in reverse order)."""

    def __init__(self, world, grid, sensor_radius_m: float):
        self.world, self.grid, self.r = world, grid, float(sensor_radius_m)
        self._lanes: dict[float, list] = {}

    def __call__(self, angle_deg: float):
        base = round(float(angle_deg) % 180.0, 9)
        if base not in self._lanes:
            self._lanes[base] = sweep_lanes(self.world, self.grid, self.r, base)
        lanes = self._lanes[base]
        return lanes[::-1] if float(angle_deg) % 360.0 >= 180.0 else lanes


def boustrophedon(lanes) -> list[np.ndarray]:
    """Pieces in driving order: even lanes forwards, odd lanes backwards (pieces reversed)."""
    order = []
    for k, lane in enumerate(lanes):
        if k % 2 == 0:
            order += [p for p in lane]
        else:
            order += [p[::-1] for p in lane[::-1]]
    return order


def ordered_pieces(lanes, order, start_xy) -> list[np.ndarray]:
    """The lanes' pieces in driving order: each lane in the direction whose first piece
    starts nearest where the robot is."""
    at = np.asarray(start_xy, float)
    out = []
    for k in order:
        forward = [np.asarray(p, float) for p in lanes[k]]
        backward = [p[::-1] for p in forward[::-1]]
        pieces = min((forward, backward), key=lambda ps: float(np.hypot(*(ps[0][0] - at))))
        out += pieces
        at = pieces[-1][1]
    return out


# --- detours over the roadmap ---------------------------------------------------------------


class FreeSegments:
    """``World.segments_free`` with the keep-out union computed and prepared once.

    (``Map.keep_out`` unions every obstacle on each access: 33 ms with 300 obstacles, paid by
    every collision query; the lawnmower and the return rule make thousands.)
    """

    def __init__(self, world):
        self.boundary = world.map.boundary
        self.keep_out = world.map.keep_out
        shapely.prepare(self.boundary)
        if not self.keep_out.is_empty:
            shapely.prepare(self.keep_out)

    def __call__(self, start_xy, end_xy) -> np.ndarray:
        """True where the straight segment stays in free space (same test as the World's)."""
        a, b = np.atleast_2d(start_xy).astype(float), np.atleast_2d(end_xy).astype(float)
        lines = shapely.linestrings(np.stack([a, b], axis=1))
        inside = shapely.covers(self.boundary, lines)
        if not self.keep_out.is_empty:
            inside &= ~shapely.intersects(self.keep_out, lines)
        return inside


class Detours:
    """Shortest collision-free paths between two points over a roadmap's geometry.

    Parameters
    ----------
    world : World (exact collision tests for the joins)
    roadmap_xy, src, dst : roadmap vertices (n, 2) [m] and directed edges (every edge both
        ways, as ``planning.roadmap.Roadmap``)
    """

    def __init__(self, world, roadmap_xy, src, dst):
        self.world = world
        self.segments_free = FreeSegments(world)
        self.xy = np.asarray(roadmap_xy, float)
        self.src, self.dst = np.asarray(src), np.asarray(dst)
        length = np.maximum(np.hypot(*(self.xy[self.dst] - self.xy[self.src]).T), 1e-9)
        n = len(self.xy)
        self.graph = csr_matrix((length, (self.src, self.dst)), shape=(n, n))
        self.tree = cKDTree(self.xy)

    def _attach(self, p) -> tuple[np.ndarray, np.ndarray]:
        k = min(K_ATTACH, len(self.xy))
        _, near = self.tree.query(p, k=k)
        near = np.atleast_1d(near)
        ok = self.segments_free(np.repeat(p[None], len(near), 0), self.xy[near])
        near = near[ok]
        return near, np.hypot(*(self.xy[near] - p).T)

    def path(self, a, b) -> np.ndarray | None:
        """Vertices a -> ... -> b of a short roadmap path, or None if not connected.

        Straight when the segment is free; else Dijkstra by length from the vertices visible
        from ``a`` (all at distance 0: a multi-source search, so the join from ``a`` is not
        weighed) to the visible vertex of ``b`` minimising path + join length.
        """
        a, b = np.asarray(a, float), np.asarray(b, float)
        if bool(self.segments_free(a[None], b[None])[0]):
            return np.array([a, b])
        na, _ = self._attach(a)
        nb, lb = self._attach(b)
        if len(na) == 0 or len(nb) == 0:
            return None
        dist, pred, _ = dijkstra(self.graph, indices=na, min_only=True,
                                 return_predecessors=True)
        total = dist[nb] + lb
        j = int(np.argmin(total))
        if not np.isfinite(total[j]):
            return None
        seq = [int(nb[j])]
        while pred[seq[-1]] >= 0:
            seq.append(int(pred[seq[-1]]))
        return clean_polyline(np.vstack([a, self.xy[seq[::-1]], b]))


# --- the path ------------------------------------------------------------------------------


def straight_route(home_xy, pieces) -> tuple[np.ndarray, np.ndarray]:
    """home -> pieces (joined by straight segments) -> home, without collision checks.

    Returns ``(xy, lane)``: vertices (n, 2) [m] and, per segment (n - 1,), True on a lane.
    """
    home = np.asarray(home_xy, float)[None]
    body = np.concatenate(pieces) if pieces else np.empty((0, 2))
    xy = np.vstack([home, body, home])
    lane = np.zeros(len(xy) - 1, dtype=bool)
    lane[1:-1:2] = True  # home->a0 join, a0->b0 lane, b0->a1 join, ...
    return xy, lane


def retrace_home(route_xy, detours: Detours) -> np.ndarray:
    """A way home from the end of ``route_xy`` (home first) when the roadmap has none from
    there: back along the route to the latest vertex the roadmap reaches home from, then
    the roadmap's path (the whole route backwards at worst: every segment of it was free).
    A lane's end a few centimetres from a wall, between two obstacles, can have no roadmap
    vertex in sight among its nearest, though the lane itself came there.

    Returns the vertices end -> ... -> home (m, 2) [m]."""
    route = np.asarray(route_xy, float)
    home = route[0]
    for k in range(len(route) - 2, 0, -1):
        ahead = detours.path(route[k], home)
        if ahead is not None:
            return np.vstack([route[k:][::-1], ahead[1:]])
    return route[::-1]


def join_pieces(home_xy, pieces, detours: Detours):
    """home -> pieces -> home with collision-free joins (straight, else a roadmap detour).

    A piece that cannot be reached is skipped. Where the roadmap has no way home from the
    last piece's end, the route is driven back (``retrace_home``).

    Returns
    -------
    (xy, lane, driven, n_detours): vertices (n, 2) [m]; per segment (n - 1,), True on a lane;
    pieces driven; joins that needed a detour.
    """
    home = np.asarray(home_xy, float)
    out, flags = [home[None]], [np.zeros(1, bool)]
    cur, driven, n_detours = home, 0, 0
    if pieces:
        starts = np.array([p[0] for p in pieces])
        prev = np.vstack([home, np.array([p[1] for p in pieces[:-1]])]) if len(pieces) > 1 \
            else home[None]
        straight_ok = detours.segments_free(prev, starts)
    for i, piece in enumerate(pieces):
        if straight_ok[i] and np.allclose(prev[i], cur):
            link = np.array([cur, piece[0]])
        else:
            link = detours.path(cur, piece[0])
            if link is None:
                continue
            n_detours += len(link) > 2
        out += [link[1:], piece[1:]]
        flags += [np.zeros(len(link) - 1, bool), np.ones(1, bool)]
        cur, driven = piece[1], driven + 1
    back = detours.path(cur, home)
    if back is None:
        back = retrace_home(np.vstack(out), detours)
    out.append(back[1:])
    flags.append(np.zeros(len(back) - 1, bool))
    xy, flag = np.vstack(out), np.concatenate(flags)
    keep = distinct_vertices(xy)  # zero-length segments
    xy, flag = xy[keep], flag[keep]
    if len(xy) < 2:
        xy, flag = np.vstack([xy, xy]), np.r_[flag, False]
    return xy, flag[1:], driven, n_detours


def cumulative_energy_time(ctx, cost, xy) -> tuple[np.ndarray, np.ndarray]:
    """Planning-model energy used [J] and mission time [s] on arrival at each vertex of a
    polyline at ``cost``'s speed, on its (fast) terrain, turning included."""
    xy = np.asarray(xy, float)
    a, b = xy[:-1], xy[1:]
    steps = subdivide(ctx.world, a, b, cost.step_m, terrain=cost.terrain)
    seg = segments_energy(ctx.model, ctx.world, None, None, cost.speed_mps, ctx.conditions,
                          steps=steps)
    turn = np.zeros(len(a))
    if len(xy) > 2:
        turn[1:] = ctx.model.turning_energy_J(heading_changes_rad(xy))
    return np.r_[0.0, np.cumsum(seg.total_J + turn)], np.r_[0.0, np.cumsum(seg.mission_time_s)]


SCORE_STEP_M = 10.0
"""Longest segment when scoring an angle: the turn point is found to within this [m]."""


def densify(xy, max_step_m: float) -> np.ndarray:
    """The polyline with every segment cut into pieces no longer than ``max_step_m`` [m]."""
    xy = np.asarray(xy, float)
    d = np.hypot(*np.diff(xy, axis=0).T)
    n = np.maximum(1, np.ceil(d / max_step_m).astype(int))
    seg = np.repeat(np.arange(len(d)), n)
    t = (np.arange(seg.size) - np.repeat(np.cumsum(n) - n, n)) / n[seg]
    return np.vstack([xy[seg] + t[:, None] * (xy[seg + 1] - xy[seg]), xy[-1:]])


def _covered_before_return(ctx, cost, xy, free, budget_J: float,
                           e_per_m_J: float) -> tuple[float, float]:
    """(area sensed before the robot must turn home [m^2], total energy [J]) on the planning
    model.

    The turn point is the first vertex (of the path cut into ``SCORE_STEP_M`` pieces) where
    energy used + straight-line energy home reaches ``budget_J``, or mission time + time home
    reaches the time limit: a cheap, rule-like stand-in to compare sweep angles, not what is
    flown. The area is the path's ``r`` buffer up to there (4 segments per quarter circle)
    within ``free`` (the free space, prepared).
    """
    xy = densify(xy, SCORE_STEP_M)
    energy, t = cumulative_energy_time(ctx, cost, xy)
    home_m = np.hypot(*(xy - xy[0]).T)
    over = energy + e_per_m_J * home_m >= budget_J
    limit = ctx.scenario.mission.time_limit_s
    if limit is not None:
        over |= t + home_m / (cost.speed_mps * ctx.conditions.duty_cycle) >= limit
    stop = int(np.argmax(over)) if over.any() else len(xy) - 1
    r = ctx.scenario.mission.sensor_radius_m
    prefix = xy[: max(stop, 1) + 1]
    area = shapely.LineString(prefix).buffer(r, quad_segs=4).intersection(free).area
    return float(area), float(energy[-1])


def best_energy_sweep_angle_deg(ctx, cost, grid, angles_deg=DEFAULT_ANGLES_DEG,
                                refine_deg: float = 5.0, detours: Detours | None = None,
                                rescore: int = 3, lanes: SweepLanes | None = None) -> float:
    """The sweep angle that senses most before the robot must turn home.

    Scored on the planning model with straight joins (``_covered_before_return``) and a
    budget of the usable energy minus the scenario's reserve when it is a fixed one (a
    confidence reserve is not known before the path; none is kept back then). Ties (the whole
    area fits) go to the cheaper path. Candidates: ``angles_deg`` and
    ``coverage.best_sweep_angle_deg`` (fewest lane pieces), each swept from either side
    (a and a + 180); the best is refined by ``+- refine_deg``. With ``detours``, the
    ``rescore`` best angles are scored again on the path with its real joins (roadmap detours
    round obstacles instead of straight lines through them). On a windy or hilly map this is
    the angle whose lanes cost least (along the wind, along the contours), which the
    fewest-turns angle ignores: the baseline gets its best sweep.
    """
    from orange_plan.physics.range import simplified_range
    from orange_plan.planning.coverage import best_sweep_angle_deg

    sc = ctx.scenario
    # no run-to-run spread counted: a confidence reserve keeps nothing back here
    budget = reserve_from(sc).budget_guess_J(sc.battery.usable_J, sc.battery.usable_J, 0.0)
    e_per_m = simplified_range(sc, ctx.model, ctx.world.default_crr).energy_per_m_J
    home = ctx.world.home_xy_m
    r = ctx.scenario.mission.sensor_radius_m

    free = ctx.world.true_map.free_space  # sensed area: the sensor sees up to the walls
    shapely.prepare(free)
    lanes = lanes or SweepLanes(ctx.world, grid, r)

    def score(angle, joined: bool = False):
        pieces = boustrophedon(lanes(angle))
        if not pieces:
            return (0.0, 0.0)
        xy = (join_pieces(home, pieces, detours) if joined else straight_route(home, pieces))[0]
        covered, energy = _covered_before_return(ctx, cost, xy, free, budget, e_per_m)
        return (round(covered, 1), -energy)

    fewest_turns = best_sweep_angle_deg(ctx.world, r)
    scores = {float(a) % 360.0: score(a) for a in (*angles_deg, fewest_turns,
                                                    fewest_turns + 180.0)}
    best = max(scores, key=scores.get)
    if refine_deg:
        for a in (best - refine_deg, best + refine_deg):
            scores[a % 360.0] = score(a % 360.0)
        best = max(scores, key=scores.get)
    if detours is not None and rescore > 0:
        top = sorted(scores, key=scores.get, reverse=True)[:rescore]
        best = max(top, key=lambda a: score(a, joined=True))
    return float(best)


def plan_lawnmower(ctx, reach=None, angle_deg: float | None = None, n_vertices: int = 2000,
                   seed: int = 0, angles_deg=DEFAULT_ANGLES_DEG,
                   lanes: SweepLanes | None = None) -> Lawnmower:
    """Lawnmower path over the scenario's free workspace at its best (or a given) angle.

    Parameters
    ----------
    ctx : Context
    reach : a ``planning.reach.Reachability`` to take the roadmap and cost contexts from
        (built here with ``n_vertices`` and ``seed`` when None)
    angle_deg : lane direction [deg]; None: ``best_energy_sweep_angle_deg``
    angles_deg : candidate angles for the search [deg]
    lanes : ``SweepLanes`` to read the lanes from (shared with other sweeps of the same
        world, grid and radius); default: made here

    Returns
    -------
    Lawnmower (home -> lanes -> home at the cruise speed)

    Raises
    ------
    PlanningError
        If no lane fits in the free workspace or home cannot be reached again.
    """
    from orange_plan.planning.coverage import coverage_grid
    from orange_plan.planning.reach import prepare_reach

    t0 = time.perf_counter()
    if reach is None:
        reach = prepare_reach(ctx, n_vertices=n_vertices, seed=seed)
    r = ctx.scenario.mission.sensor_radius_m
    grid = coverage_grid(ctx.world, r) if lanes is None else lanes.grid
    lanes = lanes or SweepLanes(ctx.world, grid, r)
    rm = reach.roadmap
    detours = Detours(ctx.world, rm.xy_m, rm.src, rm.dst)
    if angle_deg is None:
        angle_deg = best_energy_sweep_angle_deg(ctx, reach.fast, grid, angles_deg,
                                                detours=detours, lanes=lanes)
    pieces = boustrophedon(lanes(angle_deg))
    if not pieces:
        raise PlanningError(f"no lane fits in the free workspace (sensor radius {r:g} m)")
    xy, _, driven, n_detours = join_pieces(ctx.world.home_xy_m, pieces, detours)
    return Lawnmower(xy, float(angle_deg) % 360.0, 2.0 * r, float(reach.exact.speed_mps), driven,
                     n_detours, time.perf_counter() - t0)
