"""Complete sweeps: the coverage patterns the tour planner starts from, and where each turns home.

Problem (kept apart from how it is solved): among complete coverage routes of the free
workspace (home -> boustrophedon lane pieces -> home) at every sweep angle the lawnmower
baseline tries and in several lane orders, find the one that senses most before the robot
has to turn home under a homing rule, checked at every point ``v`` of the route:

    closed loop (flown):      E(v) + E_home(v) + reserve(return only)          <= E_left
    open loop (guaranteed):   E(v) + E_home(v) + reserve(E(v) + E_home(v))     <= E_left

and, with a time limit, ``t(v) + T_home(v) <= time left``. ``E(v)`` is the energy used to
reach ``v`` along the route, ``E_home(v)`` that of the way home from there
(``planning.homepaths``). A robot that measures its energy in flight knows ``E(v)``: only its
way home is still uncertain, so the closed-loop rule keeps a reserve for the return alone; a
plan that must hold without measurement (open loop) keeps it for the whole trip. The closed
loop therefore flies farther; the open-loop extent is what is guaranteed before take-off.

How it is solved: each lane order at each angle is scored with straight joins on the
planning model's fast terrain (``score_route``: the turn point to within ``step``); the best
few are joined round obstacles over the roadmap (``lawnmower.join_pieces``) and scored again,
and the baseline lawnmower's own route is always among them, so the sweep returned senses at
least as much as the baseline under the same rule, by construction. Lane orders
(``lane_orders``): edge to edge either way (the baseline's), and orders that start at the lane
nearest home and work outward, or work inward to end near home, so a mission that must turn
home early has covered what is near home and keeps its way home short (an anytime order).
Pieces of one lane are driven in the direction whose first piece starts nearest the robot.
Beside them, cell sweeps (``planning.cells``): the free space cut into boustrophedon cells,
each swept at its own angle or on the whole map's lanes, cell by cell (``cell_candidates``);
each kind's best few are joined and scored again, so adding them never drops a whole-map
sweep that would have been kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from orange_plan.errors import PlanningError
from orange_plan.planning.coverage import best_sweep_angle_deg
from orange_plan.planning.lawnmower import (
    DEFAULT_ANGLES_DEG,
    SweepLanes,
    cumulative_energy_time,
    densify,
    join_pieces,
    ordered_pieces,
    straight_route,
)
from orange_plan.planning.paths import cut_path
from orange_plan.planning.reserve import normal_quantiles, reserve_from

RESCORE = 4
"""Best straight-joined sweeps joined round obstacles and scored again."""


@dataclass(frozen=True)
class RouteScore:
    """Where a route turns home under the closed- and open-loop rules (module docstring).

    Attributes
    ----------
    closed_s_m, open_s_m : arclength of the turn point [m] (the route's length: never turns)
    closed_m2, open_m2 : area sensed up to there [m^2]
    closed_used_J : planning-model energy used up to the closed-loop turn [J]
    length_m : the route's length [m]
    """

    closed_s_m: float
    open_s_m: float
    closed_m2: float
    open_m2: float
    closed_used_J: float
    length_m: float


@dataclass(frozen=True)
class Sweep:
    """A complete coverage route and its score.

    Attributes
    ----------
    xy_m : home -> lane pieces -> home, joined round obstacles [m]
    angle_deg : lane direction [deg]; for a cell sweep, the decomposition direction
    order : lane order name (``lane_orders``; "baseline": the lawnmower's own route; for a
        cell sweep ``cells.CELL_ORDERS``)
    score : ``RouteScore`` on the joined route
    tried : patterns scored (angle and lane order, decomposition and cell order)
    cells : 0 for a whole-map sweep, else the cells swept
    per_cell_angles : a cell sweep whose cells each have their own angle
    rivals : (pattern, closed_m2, open_m2) of every route joined and scored again
    spread_m2 : area sensed before the closed-loop turn at each budget of
        ``spread_factors`` [m^2]
    spread_factors : the budgets of the spread, as factors of the energy left [-]
    """

    xy_m: np.ndarray
    angle_deg: float
    order: str
    score: RouteScore
    tried: int
    cells: int = 0
    per_cell_angles: bool = False
    rivals: tuple = ()
    spread_m2: tuple = ()
    spread_factors: tuple = ()

    @property
    def pattern(self) -> str:
        """What the route is, in words."""
        return _pattern(self.angle_deg, self.order, self.cells, self.per_cell_angles)


def _pattern(angle_deg: float, order: str, cells: int, per_cell: bool) -> str:
    if order == "baseline":
        return "sweep: the lawnmower's own route"
    if cells == 1:
        return f"sweep of the whole free space as one cell, {order} order"
    if cells:
        lanes = "each at its own angle" if per_cell else f"lanes at {angle_deg:g} deg"
        return (f"{cells} cells cut along {angle_deg:g} deg, {lanes}, joined "
                f"{order}")
    return f"sweep at {angle_deg:g} deg, {order} lane order"


def lane_orders(lanes, home_xy) -> dict[str, list[int]]:
    """Orders of the lanes (indices in sweep order) to try.

    ``edge``: first to last lane; ``out_*``: from the lane nearest home outward to one edge,
    then from beside home outward to the other; ``in_*``: from one edge inward to home, then
    from the other edge inward (the route ends near home).
    """
    n = len(lanes)
    if n == 0:
        return {}
    home = np.asarray(home_xy, float)
    near = [min(float(np.min(np.hypot(*(np.asarray(p) - home).T))) for p in lane)
            for lane in lanes]
    h = int(np.argmin(near))
    up, down = list(range(h, n)), list(range(h - 1, -1, -1))
    orders = {"edge": list(range(n)),
              "out_up": up + down, "out_down": list(range(h, -1, -1)) + list(range(h + 1, n)),
              "in_up": list(range(h + 1)) + list(range(n - 1, h, -1)),
              "in_down": list(range(n - 1, h - 1, -1)) + list(range(h))}
    unique, seen = {}, set()
    for name, order in orders.items():
        if tuple(order) not in seen:
            seen.add(tuple(order))
            unique[name] = order
    return unique


def score_route(ctx, cost, home, grid, xy, e_left_J: float, time_left_s: float,
                step_m: float, max_length_m: float = math.inf, reserve=None) -> RouteScore:
    """Turn points of a route under both rules (module docstring), on the planning model.

    Parameters
    ----------
    ctx : Context; cost : edge-cost context (its speed and terrain: the reach's fast one)
    home : ``homepaths.HomePaths``; grid : the coverage grid (area sensed)
    xy : the route [m]; e_left_J : energy left to spend [J]; time_left_s : [s] (inf: none)
    step_m : the route is cut into pieces at most this long (the turn's resolution) [m]
    reserve : the reserve rule (``planning.reserve``; default: the scenario's)
    max_length_m : no robot can drive farther (``tour.drivable_m``): the route is scored up
        to there only (a long sweep on a time-limited mission is mostly never reached) [m]
    """
    return route_needs(ctx, cost, home, xy, time_left_s, step_m, max_length_m,
                       reserve).score(grid, e_left_J, ctx.scenario.mission.sensor_radius_m)


@dataclass(frozen=True)
class RouteNeeds:
    """What each point of a densely cut route needs under the two homing rules, whatever
    the budget: the turn points for any energy left follow from it (``score``,
    ``closed_m2_over``).

    Attributes
    ----------
    full_xy_m : the route as given [m]; s_m : arclength of each dense point [m]
    closed_J, open_J : energy the closed- and open-loop rules need at each dense point [J]
    late : the way home from there would end past the time limit
    used_J : planning-model energy used to reach each dense point [J]
    length_m : the route's length [m]
    """

    full_xy_m: np.ndarray
    s_m: np.ndarray
    closed_J: np.ndarray
    open_J: np.ndarray
    late: np.ndarray
    used_J: np.ndarray
    length_m: float

    def _turn(self, needed_J: np.ndarray, e_left_J: float) -> int:
        """Index of the dense point where a rule needing ``needed_J`` turns home [-]."""
        return _last_ok(~((needed_J > e_left_J) | self.late))

    def closed_turn_m(self, e_left_J: float) -> float:
        """Arclength of the closed-loop turn with ``e_left_J`` to spend [m]."""
        return float(self.s_m[self._turn(self.closed_J, e_left_J)])

    def closed_m2_over(self, grid, budgets_J, r: float) -> tuple[float, ...]:
        """Area sensed before the closed-loop rule turns home, for each budget [m^2]; the
        area is counted once per distinct turn point (a time limit or a route sensed whole
        turns them all at one point)."""
        turns = [self.closed_turn_m(b) for b in budgets_J]
        area = {s: _sensed_m2(grid, cut_path(self.full_xy_m, s), r) for s in set(turns)}
        return tuple(area[s] for s in turns)

    def score(self, grid, e_left_J: float, r: float) -> RouteScore:
        """Both turn points and the area sensed up to each with ``e_left_J`` to spend."""
        k_closed = self._turn(self.closed_J, e_left_J)
        k_open = self._turn(self.open_J, e_left_J)
        s = self.s_m
        # the area from the route's own vertices (the dense cut only places the turn)
        closed_m2 = _sensed_m2(grid, cut_path(self.full_xy_m, s[k_closed]), r)
        open_m2 = (closed_m2 if k_open == k_closed
                   else _sensed_m2(grid, cut_path(self.full_xy_m, s[k_open]), r))
        return RouteScore(float(s[k_closed]), float(s[k_open]), closed_m2, open_m2,
                          float(self.used_J[k_closed]), self.length_m)


def route_needs(ctx, cost, home, xy, time_left_s: float, step_m: float,
                max_length_m: float = math.inf, reserve=None) -> RouteNeeds:
    """``RouteNeeds`` of a route (the arguments as ``score_route``'s)."""
    full = np.asarray(xy, float)
    length = float(np.sum(np.hypot(*np.diff(full, axis=0).T)))
    xy = densify(cut_path(full, max_length_m), step_m)
    used, t = cumulative_energy_time(ctx, cost, xy)
    back, var_back, back_m = _returns_along(home, xy, ctx.model)
    reserve = reserve_from(ctx.scenario) if reserve is None else reserve
    e_avail = ctx.scenario.battery.usable_J
    closed = used + back + reserve.return_only_J(back, var_back, e_avail)
    # open loop: the whole trip's variance, the return's relative spread applied to it (the
    # exact check of the plan recomputes it from the walk's own gradient)
    total = used + back
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(back > 0, np.sqrt(var_back) / back, ctx.model.discrepancy_rel_sd)
    opened = total + reserve.size_J(total, (rel * total) ** 2, e_avail)
    time_home = back_m / (home.speed_mps * max(ctx.conditions.duty_cycle, 1e-9))
    late = t + time_home > time_left_s
    s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]
    return RouteNeeds(full, s, closed, opened, late, used, length)


RETURN_LOOKUPS = 400
"""Points of a scored route whose way home is looked up; the others are interpolated (the
way home changes smoothly along a route; the lookups' collision checks are most of a
score's time)."""


def _returns_along(home, xy, model):
    """``home.returns`` at every point of a densely cut route, looked up at most at
    ``RETURN_LOOKUPS`` of them (evenly spaced, ends included) and interpolated by arclength
    between (the way home changes little over a few metres; the lookups' collision checks
    dominate the scoring otherwise)."""
    n = len(xy)
    if n <= RETURN_LOOKUPS:
        return home.returns(xy, model)
    s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]
    pick = np.unique(np.linspace(0, n - 1, RETURN_LOOKUPS).round().astype(int))
    looked = home.returns(xy[pick], model)
    # a point between a lookup with no way home and one with a way is treated as having none
    return tuple(np.nan_to_num(np.interp(s, s[pick], values), nan=np.inf) for values in looked)


def _last_ok(ok: np.ndarray) -> int:
    """Index of the last point before the first one that breaks the rule (0: turn at once;
    the last point when none breaks it)."""
    bad = np.flatnonzero(~ok)
    return len(ok) - 1 if bad.size == 0 else max(int(bad[0]) - 1, 0)


def _sensed_m2(grid, xy, r: float) -> float:
    if len(xy) < 2:
        xy = np.vstack([xy, xy])
    return float(len(grid.cells_near(xy, r)) * grid.cell_area_m2)


def score_step_m(ctx) -> float:
    """Resolution of the turn point: a tenth of the sensor's width, 0.2 to 10 m [m]."""
    return float(np.clip(0.2 * ctx.scenario.mission.sensor_radius_m, 0.2, 10.0))


DECOMPOSITIONS = 3
"""Decomposition directions of the cell sweeps: the whole map's fewest-turns angle, the
angle across it and the best-scoring whole-map angle (when distinct)."""


@dataclass(frozen=True)
class _Candidate:
    """A route's lane pieces before they are joined round obstacles."""

    angle_deg: float
    order: str
    pieces: list
    cells: int = 0
    per_cell_angles: bool = False


def cell_candidates(world, lanes: SweepLanes, home_xy, directions_deg, segments_free):
    """Cell sweeps (``planning.cells``) along each decomposition direction: cells at their
    own angles and at the decomposition's, in every cell order."""
    from orange_plan.planning.cells import CELL_ORDERS, cell_pieces, decompose, swept_cells

    out, seen = [], set()
    for direction in directions_deg:
        polygons = decompose(world.map.free_space, direction, lanes.r)
        if len(polygons) < 2:  # one cell: the whole-map sweeps already hold it
            continue
        for per_cell in (True, False):
            cells = swept_cells(world, polygons, lanes.r, None if per_cell else direction,
                                segments_free, lanes.grid.free_space)
            for how in CELL_ORDERS:
                pieces = cell_pieces(cells, how, home_xy)
                key = np.concatenate(pieces).round(6).tobytes() if pieces else b""
                if pieces and key not in seen:  # merged cells repeat across directions
                    seen.add(key)
                    out.append(_Candidate(direction, how, pieces, len(cells), per_cell))
    return out


def best_sweep(ctx, reach, home, grid, detours, baseline_xy=None, e_left_J: float | None = None,
               time_left_s: float = math.inf, max_length_m: float = math.inf,
               angles_deg=DEFAULT_ANGLES_DEG, rescore: int | None = None,
               lanes: SweepLanes | None = None, cells: bool = True,
               run_sd: float | None = None) -> Sweep | None:
    """The complete sweep expected to sense most before the closed-loop rule turns it home.

    The ``rescore`` best whole-map sweeps and the ``CELL_RESCORE`` best cell sweeps by the
    straight-joined score (at ``e_left_J``) are joined round obstacles and scored again over
    a spread of budgets (``budget_factors``: the run's energy differs from the model's by
    ``run_sd``, default the model's ``discrepancy_rel_sd``, and a closed loop turns home
    earlier or later with it); the one of the largest mean area over the spread is kept
    (``choose_sweep``). ``baseline_xy`` (the lawnmower's route, joined) is scored on the same
    terms, and another sweep replaces it only when it senses at least as much at every
    budget of the spread. None when no lane fits. ``cells``: the cell sweeps
    (``cell_candidates``) are candidates too.
    """
    r = ctx.scenario.mission.sensor_radius_m
    rescore = RESCORE if rescore is None else rescore
    cost = reach.fast
    home_xy = np.asarray(reach.home_xy_m, float)
    if e_left_J is None:
        e_left_J = reach.energy_available_J - reach.energy_used_J
    step = score_step_m(ctx)
    lanes = lanes or SweepLanes(ctx.world, grid, r)

    def score(xy) -> RouteScore:
        return score_route(ctx, cost, home, grid, xy, e_left_J, time_left_s, step,
                           max_length_m, reach.reserve)

    def rank(s: RouteScore):
        return (round(s.closed_m2, 3), round(s.open_m2, 3), -s.closed_used_J)

    angles = sorted({float(a) % 180.0 for a in angles_deg})
    straight = []

    def add(candidate: _Candidate) -> None:
        xy = straight_route(home_xy, candidate.pieces)[0]
        straight.append((rank(score(xy)), candidate))

    for angle in angles:
        at = lanes(angle)
        for name, order in lane_orders(at, home_xy).items():
            add(_Candidate(angle, name, ordered_pieces(at, order, home_xy)))
    if cells:
        best_whole = max(straight, key=lambda item: item[0])[1].angle_deg if straight else 0.0
        fewest = best_sweep_angle_deg(ctx.world, r)
        directions = list(dict.fromkeys(round(a % 180.0, 6) for a in
                                        (fewest, fewest + 90.0, best_whole)))
        for candidate in cell_candidates(ctx.world, lanes, home_xy,
                                         directions[:DECOMPOSITIONS], detours.segments_free):
            add(candidate)
    tried = len(straight)
    factors = budget_factors(ctx.model.discrepancy_rel_sd if run_sd is None else run_sd)
    budgets = e_left_J * factors

    def scored(xy, angle_deg, order, *cell) -> Sweep:
        needs = route_needs(ctx, cost, home, xy, time_left_s, step, max_length_m,
                            reach.reserve)
        spread = needs.closed_m2_over(grid, budgets, r)
        return Sweep(xy, angle_deg, order, needs.score(grid, e_left_J, r), tried, *cell,
                     spread_m2=spread, spread_factors=tuple(float(f) for f in factors))

    joined = []
    for candidate in _to_rescore(straight, rescore):
        try:
            xy = join_pieces(home_xy, candidate.pieces, detours)[0]
        except PlanningError:  # its last lane end has no way home on this roadmap
            continue
        joined.append(scored(xy, candidate.angle_deg, candidate.order, candidate.cells,
                             candidate.per_cell_angles))
    base = None
    if baseline_xy is not None:
        base = scored(np.asarray(baseline_xy, float), math.nan, "baseline")
        joined.append(base)
    if not joined:
        return None
    rivals = tuple((s.pattern, s.score.closed_m2, s.score.open_m2) for s in joined)
    return replace(choose_sweep(joined, base, rank), rivals=rivals)


BUDGET_QUANTILES = (0.1, 0.25, 0.5, 0.75, 0.9)
"""Quantiles of the run's energy over the model's at which a sweep is scored [-]."""


def budget_factors(run_sd: float) -> np.ndarray:
    """Budgets a closed loop effectively flies on, as factors of the energy left [-].

    A run whose energy is ``k`` times the model's (``k`` normal around 1 with sd
    ``run_sd``, taken at ``BUDGET_QUANTILES``, never below 0.5) turns home about where the
    model would with ``1 / k`` of the energy: the rule measures what it spends and learns
    ``k`` on the way out. 1 alone when ``run_sd`` is 0.
    """
    k = 1.0 + max(float(run_sd), 0.0) * normal_quantiles(BUDGET_QUANTILES)
    return np.unique(1.0 / np.maximum(k, 0.5))


def choose_sweep(joined, base, rank) -> Sweep:
    """The sweep of the largest mean area over the budget spread (``Sweep.spread_m2``;
    ties by ``rank`` of the score at the budget itself) among those that sense at least as
    much as ``base`` (the baseline's sweep, None: no such bound) at every budget. A rival
    that only ties ``base`` on the mean area does not replace it: the coverage grid cannot
    tell the two apart, and what it cannot see the baseline's route is known to sense."""
    if base is not None:
        floor = np.asarray(base.spread_m2, float)
        joined = [s for s in joined if s is base
                  or bool(np.all(np.asarray(s.spread_m2, float) >= floor - 1e-6))]
    return max(joined, key=lambda s: (round(float(np.mean(s.spread_m2)), 3), s is base,
                                      rank(s.score)))


CELL_RESCORE = 2
"""Best straight-joined cell sweeps joined round obstacles and scored again (beside the
``rescore`` best whole-map sweeps)."""


def _to_rescore(straight, rescore: int) -> list[_Candidate]:
    """The ``rescore`` best straight-joined whole-map sweeps and the ``CELL_RESCORE`` best
    cell sweeps: each kind ranked on its own, so adding the cell sweeps never drops a
    whole-map sweep that would have been joined."""
    ranked = [c for _, c in sorted(straight, key=lambda item: item[0], reverse=True)]
    return ([c for c in ranked if c.cells == 0][:rescore]
            + [c for c in ranked if c.cells > 0][:CELL_RESCORE])
