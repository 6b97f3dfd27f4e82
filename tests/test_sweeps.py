"""Complete sweeps (planning.sweeps), the session's energy rule in flight (bench.px4_rtl
EnergyRule) and the sweep tour of the planner: hand-computed turn points, lane orders, and
the property that the planner's closed-loop route senses at least what the lawnmower does
under the same rule."""

from __future__ import annotations

import functools
import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import shapely
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from planning_worlds import draw_world_spec, write_world

from orange_plan.bench.plan import driven_home
from orange_plan.bench.px4_rtl import EnergyRule
from orange_plan.context import load_context
from orange_plan.errors import InputError, PlanningError
from orange_plan.planning.coverage import coverage_grid
from orange_plan.planning.homepaths import HomePaths
from orange_plan.planning.lawnmower import (
    DEFAULT_ANGLES_DEG,
    cumulative_energy_time,
    plan_lawnmower,
)
from orange_plan.planning.plan import StartState
from orange_plan.planning.reach import prepare_reach
from orange_plan.planning.reserve import EnergyReserve, closed_loop_return_spread
from orange_plan.planning.sweeps import lane_orders, ordered_pieces, score_route, score_step_m
from orange_plan.planning.tour import (
    drivable_m,
    driven_energy_J,
    route_after,
    sweep_tour,
    tour_setup,
)


def _lanes(n: int, length: float = 10.0, spacing: float = 2.0):
    """n horizontal lanes of one piece each, ``spacing`` apart, from y = 0 up."""
    return [[np.array([[0.0, k * spacing], [length, k * spacing]])] for k in range(n)]


def test_lane_orders_start_beside_home_and_cover_every_lane_once():
    lanes = _lanes(5)
    orders = lane_orders(lanes, (0.0, 4.1))  # home beside lane 2
    assert orders["edge"] == [0, 1, 2, 3, 4]
    assert orders["out_up"] == [2, 3, 4, 1, 0]
    assert orders["out_down"] == [2, 1, 0, 3, 4]
    assert orders["in_up"] == [0, 1, 2, 4, 3]  # ends beside home
    assert orders["in_down"] == [4, 3, 2, 0, 1]
    for order in orders.values():
        assert sorted(order) == list(range(5))


def test_lane_orders_drop_repeats_and_handle_no_lanes():
    assert lane_orders([], (0.0, 0.0)) == {}
    orders = lane_orders(_lanes(3), (0.0, -5.0))  # home below lane 0: "out" is "edge"
    assert orders == {"edge": [0, 1, 2], "in_up": [0, 2, 1], "in_down": [2, 1, 0]}


def test_ordered_pieces_drive_each_lane_from_its_nearer_end():
    pieces = ordered_pieces(_lanes(3), [0, 1, 2], (0.0, 0.0))
    assert np.allclose(pieces[0], [[0, 0], [10, 0]])   # from home's end
    assert np.allclose(pieces[1], [[10, 2], [0, 2]])   # back: boustrophedon
    assert np.allclose(pieces[2], [[0, 4], [10, 4]])


class _HomeAt:
    """Ways home of a constant energy per metre straight to ``home`` (a hand-checkable
    stand-in for ``HomePaths``)."""

    def __init__(self, per_m: float, sd_rel: float = 0.0, speed_mps: float = 1.0,
                 home=(0.0, 0.0)):
        self.per_m, self.sd_rel, self.speed_mps = per_m, sd_rel, speed_mps
        self.home = np.asarray(home, float)

    def returns(self, points, model):
        d = np.hypot(*(np.atleast_2d(points) - self.home).T)
        e = self.per_m * d
        return e, (self.sd_rel * e) ** 2, d


def _corridor(tmp_path, reserve):
    path = write_world(tmp_path, width_m=60.0, height_m=10.0, home=(1.0, 5.0), reserve=reserve,
                       rated_energy_Wh=1.0)
    return load_context(path)


def test_score_route_turns_where_the_energy_used_meets_the_budget(tmp_path):
    ctx = _corridor(tmp_path, {"energy_J": 0.0})
    reach = prepare_reach(ctx, n_vertices=150)
    grid = coverage_grid(ctx.world, ctx.scenario.mission.sensor_radius_m)
    route = np.array([[1.0, 5.0], [55.0, 5.0], [1.0, 5.0]])
    used, _ = cumulative_energy_time(ctx, reach.fast, np.array([[1.0, 5.0], [55.0, 5.0]]))
    budget = 0.5 * used[-1]  # free ways home: the turn is where half of the lane's energy is
    s = score_route(ctx, reach.fast, _HomeAt(0.0), grid, route, budget, math.inf, 0.1)
    assert s.closed_s_m == pytest.approx(27.0, abs=0.6)
    assert s.open_s_m == pytest.approx(s.closed_s_m)
    assert s.length_m == pytest.approx(108.0)
    # a way home at the lane's energy per metre e: e s + e s = e 27 on the flat lane
    e = used[-1] / 54.0
    s2 = score_route(ctx, reach.fast, _HomeAt(e, home=(1.0, 5.0)), grid, route, budget,
                     math.inf, 0.1)
    assert s2.closed_s_m == pytest.approx(13.5, abs=0.6)
    assert s2.closed_m2 < s.closed_m2


def test_open_loop_keeps_a_reserve_for_the_whole_trip_the_closed_loop_for_the_return(tmp_path):
    ctx = _corridor(tmp_path, {"confidence": 0.95})
    reach = prepare_reach(ctx, n_vertices=150)
    grid = coverage_grid(ctx.world, ctx.scenario.mission.sensor_radius_m)
    route = np.array([[1.0, 5.0], [55.0, 5.0], [1.0, 5.0]])
    used, _ = cumulative_energy_time(ctx, reach.fast, route[:2])
    e = used[-1] / 54.0
    s = score_route(ctx, reach.fast, _HomeAt(e, sd_rel=0.25, home=(1.0, 5.0)), grid, route,
                    0.6 * used[-1],
                    math.inf, 0.1, reserve=reach.reserve)
    assert s.open_s_m < s.closed_s_m
    assert s.open_m2 <= s.closed_m2


def test_score_route_stops_at_the_time_limit(tmp_path):
    ctx = _corridor(tmp_path, {"energy_J": 0.0})
    reach = prepare_reach(ctx, n_vertices=150)
    grid = coverage_grid(ctx.world, ctx.scenario.mission.sensor_radius_m)
    route = np.array([[1.0, 5.0], [55.0, 5.0]])
    _, t = cumulative_energy_time(ctx, reach.fast, route)
    s = score_route(ctx, reach.fast, _HomeAt(0.0, speed_mps=1e9), grid, route, math.inf,
                    0.25 * t[-1], 0.1)
    assert s.closed_s_m == pytest.approx(0.25 * 54.0, abs=0.6)


def _frame(power_W: float, n: int, dt: float = 0.1, v: float = 1.0):
    t = np.arange(n) * dt
    return pd.DataFrame({"t_s": t, "power_W": np.full(n, power_W), "x_m": v * t,
                         "y_m": np.zeros(n), "v_mps": np.full(n, v)})


def test_energy_rule_fires_where_used_plus_home_plus_lookahead_meets_the_battery():
    usable = 1000.0
    ctx = SimpleNamespace(scenario=SimpleNamespace(
        battery=SimpleNamespace(usable_J=usable),
        mission=SimpleNamespace(time_limit_s=None, reserve=EnergyReserve(100.0))),
        conditions=SimpleNamespace(duty_cycle=1.0), model=None)
    frame = _frame(10.0, 2000)  # 10 W, 1 m/s out along x; home costs 5 J/m
    rule = EnergyRule(time_factor=1.0, power_window_s=1e-9)
    d = rule.decide(ctx, frame, np.array([[0.0, 0.0], [200.0, 0.0]]),
                    _HomeAt(5.0), cost=None)
    # 10 t (used) + 20 (two seconds ahead) + 5 t (home) + 100 >= 1000  ->  t >= 58.67 s,
    # checked once a second
    assert d.fired and d.t_s == pytest.approx(59.0, abs=0.11)
    assert d.s_m == pytest.approx(d.t_s, abs=0.2)


def test_energy_rule_never_fires_on_a_route_that_fits():
    ctx = SimpleNamespace(scenario=SimpleNamespace(
        battery=SimpleNamespace(usable_J=1e6),
        mission=SimpleNamespace(time_limit_s=None, reserve=EnergyReserve(0.0))),
        conditions=SimpleNamespace(duty_cycle=1.0), model=None)
    d = EnergyRule().decide(ctx, _frame(10.0, 100), np.array([[0.0, 0.0], [10.0, 0.0]]),
                            _HomeAt(1.0), cost=None)
    assert not d.fired


def _candidate(spread, nominal):
    return SimpleNamespace(spread_m2=tuple(spread), score=SimpleNamespace(closed_m2=nominal))


def test_a_sweep_replaces_the_lawnmower_only_if_it_senses_as_much_at_every_budget():
    """A sweep that senses more at the budget itself but less than the lawnmower when the
    run turns out dearer is not kept; one at least as good everywhere is, and among those
    the largest mean over the spread wins."""
    from orange_plan.planning.sweeps import choose_sweep

    def rank(score):
        return (score.closed_m2,)

    base = _candidate([100, 200, 300], 200)
    greedy = _candidate([80, 260, 400], 260)  # more at the budget, less on a dear run
    assert choose_sweep([greedy, base], base, rank) is base
    steady = _candidate([100, 210, 320], 210)
    bold = _candidate([101, 200, 330], 200)
    assert choose_sweep([greedy, steady, bold, base], base, rank) is bold
    assert choose_sweep([greedy, steady], None, rank) is greedy  # no lawnmower: the mean


def test_a_sweep_that_only_ties_the_lawnmower_does_not_replace_it():
    """On a map every sweep covers whole, all tie on the coverage grid: the lawnmower's route
    is kept even when a rival ranks higher at the budget itself (cheaper, say), since the
    grid cannot show what the rival might miss between its cells."""
    from orange_plan.planning.sweeps import choose_sweep

    def rank(score):
        return (score.closed_m2,)

    base = _candidate([300, 300, 300], 300)
    cheaper = _candidate([300, 300, 300], 301)
    assert choose_sweep([cheaper, base], base, rank) is base
    assert choose_sweep([base, cheaper], base, rank) is base


def test_budget_factors_span_dearer_and_cheaper_runs():
    from orange_plan.planning.sweeps import budget_factors

    assert np.allclose(budget_factors(0.0), [1.0])
    f = budget_factors(0.25)
    assert f.min() < 0.8 < 1.25 < f.max() and np.any(np.isclose(f, 1.0))
    assert np.all(budget_factors(5.0) <= 2.0)  # a run never counted below half the model


def test_route_after_is_the_rest_of_the_route():
    route = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    rest = route_after(route, 4.0)
    assert np.allclose(rest, [[4.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    assert np.allclose(route_after(route, 20.0)[-1], [10.0, 10.0])


@st.composite
def worlds(draw):
    spec = draw_world_spec(draw, width_cells=(12, 20), height_cells=(8, 14), box_cells=(3, 5),
                           hill_height_m=4.0, ramp_max=0.1, surface_width_m=8.0)
    reserve = draw(st.sampled_from([{"fraction": 0.1}, {"confidence": 0.95},
                                    {"energy_J": 200.0}]))
    return dict(spec, reserve=reserve, rated_energy_Wh=draw(st.floats(0.15, 1.2)))


def _closed_loop(ctx):
    """``ctx`` with the return reserve the closed loop keeps, the rule sweeps are chosen by."""
    return replace(ctx, model=ctx.model.with_discrepancy(closed_loop_return_spread(ctx.model)))


def _assert_home_to_home(swept, ctx):
    """The plan starts and ends at home with every margin >= 0; its closed-loop route ends at
    home. Returns that route."""
    home_xy = np.asarray(ctx.world.home_xy_m)
    assert np.allclose(swept.xy_m[0], home_xy) and np.allclose(swept.xy_m[-1], home_xy)
    assert np.all(swept.margin_J >= 0)
    route = swept.closed_loop_route()[0]
    assert np.allclose(route[-1], home_xy)
    return route


# A tiny budget where a sweep chosen at the budget alone (2 cells at 110 deg) sensed 13 %
# less than the lawnmower on another roadmap's ways home: its turn fell just before a lane
# end. Chosen over the budget spread, the plan keeps a sweep as good at every budget.
TINY_BUDGET = {"width_m": 36.0, "height_m": 18.0, "obstacles": [(12.0, 14.0, 18.0, 18.0)],
               "hill": None, "ramp": 0.0,
               "surfaces": [(24.0, 0.0, 32.0, 18.0, 0.14279846575665095)],
               "reserve": {"confidence": 0.95}, "rated_energy_Wh": 0.3}


@pytest.mark.timeout(280)
@settings(max_examples=6, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(spec=worlds())
@example(spec=TINY_BUDGET)
def test_the_plan_senses_at_least_the_lawnmower_under_the_same_rule(tmp_path_factory, spec):
    """By construction: on the planner's own roadmap and rule, the sweep it keeps is expected
    to sense at least what the lawnmower route does. Independently: one fresh roadmap's ways
    home score both routes alike (roadmaps differ: within 10 %). Every plan starts and ends
    at home with every margin >= 0, and its continuation stays in free space and ends home."""
    ctx = load_context(write_world(tmp_path_factory.mktemp("sweep"), **spec))
    start = StartState()
    try:
        setup = tour_setup(ctx, start, 250, 0, 40, lambda text: None)
    except InputError:
        return
    swept = sweep_tour(ctx, setup, start, t0=0.0, optimise_speed=False)
    if swept is None:
        return
    route = _assert_home_to_home(swept, ctx)
    assert ctx.world.segments_free(route[:-1], route[1:]).all()

    reach = setup.reach
    home = HomePaths(reach).calibrate(functools.partial(driven_energy_J, reach.exact))
    left = reach.energy_available_J
    limit = ctx.scenario.mission.time_limit_s or math.inf
    lawn = plan_lawnmower(ctx, reach).xy_m
    # the closed loop's rule: the floor of the a-priori discrepancy kept for the return
    flown = _closed_loop(ctx)
    own = score_route(flown, reach.fast, home, setup.grid, lawn, left, limit,
                      score_step_m(ctx), 1.05 * drivable_m(ctx, reach, limit), reach.reserve)
    assert swept.summary["closed_loop_coverage_m2"] >= own.closed_m2 - 1e-6

    fresh = prepare_reach(ctx, n_vertices=250, seed=1)
    other = driven_home(fresh)

    def sensed(xy):  # under the same closed-loop rule the sweep was chosen by
        return score_route(flown, fresh.fast, other, setup.grid, xy, left, limit, 0.5).closed_m2

    assert sensed(route) >= 0.9 * sensed(lawn) - 2 * setup.grid.cell_area_m2


@st.composite
def obstacle_worlds(draw):
    spec = draw_world_spec(draw, width_cells=(12, 20), height_cells=(8, 14), box_cells=(3, 5),
                           hill_height_m=4.0, ramp_max=0.1, surface_width_m=8.0)
    return dict(spec, reserve=draw(st.sampled_from([{"fraction": 0.1}, {"confidence": 0.95}])),
                rated_energy_Wh=draw(st.floats(0.15, 1.2)),
                radius_m=draw(st.sampled_from([None, 0.3])))


def _every_sweep_joined(ctx, setup, home, detours, lanes, e_left, limit, max_m, run_sd):
    """Every candidate of ``best_sweep`` (each angle and lane order, each decomposition, cell
    angle rule and cell order) joined round obstacles and scored over the budgets of
    ``run_sd``, independently of it."""
    from orange_plan.planning.coverage import best_sweep_angle_deg
    from orange_plan.planning.lawnmower import join_pieces
    from orange_plan.planning.sweeps import cell_candidates

    home_xy = np.asarray(setup.reach.home_xy_m, float)
    pieces = []
    for angle in sorted({float(a) % 180.0 for a in DEFAULT_ANGLES_DEG}):
        at = lanes(angle)
        pieces += [ordered_pieces(at, o, home_xy) for o in lane_orders(at, home_xy).values()]
    r = ctx.scenario.mission.sensor_radius_m
    fewest = best_sweep_angle_deg(ctx.world, r)
    for direction in (fewest, (fewest + 90.0) % 180.0):
        pieces += [c.pieces for c in cell_candidates(ctx.world, lanes, home_xy, [direction],
                                                     detours.segments_free)]
    scores = []
    for p in pieces:
        try:
            xy = join_pieces(home_xy, p, detours)[0]
        except PlanningError:
            continue
        scores.append(_spread(ctx, setup, home, xy, e_left, limit, max_m, run_sd))
    return scores


def _spread(ctx, setup, home, xy, e_left, limit, max_m, run_sd=None) -> np.ndarray:
    """Area a route senses before the closed-loop turn at each budget of the spread
    (``budget_factors`` of the a-priori discrepancy), recomputed with ``route_needs``."""
    from orange_plan.planning.sweeps import budget_factors, route_needs

    reach, r = setup.reach, ctx.scenario.mission.sensor_radius_m
    run_sd = ctx.model.discrepancy_rel_sd if run_sd is None else run_sd
    needs = route_needs(ctx, reach.fast, home, xy, limit, score_step_m(ctx), max_m,
                        reach.reserve)
    return np.array(needs.closed_m2_over(setup.grid, e_left * budget_factors(run_sd), r))


@pytest.mark.timeout(600)
@settings(max_examples=5, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(spec=obstacle_worlds())
# a sweep whose budgets were once recomputed over the closed loop's narrower spread, not the
# run's: it looked better than the plan at the middle budgets
@example(spec={"width_m": 40.0, "height_m": 16.0, "obstacles": [], "hill": (0.0, 0.0, 1.0, 3.0),
               "ramp": 0.0, "surfaces": [(0.0, 0.0, 8.0, 16.0, 0.0234375)],
               "reserve": {"fraction": 0.1}, "rated_energy_Wh": 0.15625, "radius_m": None})
def test_the_plan_senses_at_least_every_sweep_whole_map_or_cell_by_cell(
        tmp_path_factory, monkeypatch, spec):
    """With every candidate joined and scored (``RESCORE``, ``CELL_RESCORE`` above their
    count), the plan's closed-loop coverage is at least that of each whole-map sweep and each
    cell sweep under the same homing rule, each recomputed here; the plan starts and ends at
    home, keeps every margin >= 0, and its route keeps the robot's radius off every obstacle
    and the boundary."""
    from orange_plan.planning import sweeps
    from orange_plan.planning.lawnmower import Detours, SweepLanes

    monkeypatch.setattr(sweeps, "RESCORE", 10_000)
    monkeypatch.setattr(sweeps, "CELL_RESCORE", 10_000)
    ctx = load_context(write_world(tmp_path_factory.mktemp("cells"), **spec))
    start = StartState()
    try:
        setup = tour_setup(ctx, start, 250, 0, 40, lambda text: None)
    except InputError:
        return
    reach = setup.reach
    home = HomePaths(reach).calibrate(functools.partial(driven_energy_J, reach.exact))
    rm = reach.roadmap
    detours = Detours(ctx.world, rm.xy_m, rm.src, rm.dst)
    lanes = SweepLanes(ctx.world, setup.grid, ctx.scenario.mission.sensor_radius_m)
    limit = ctx.scenario.mission.time_limit_s or math.inf
    max_m = 1.05 * drivable_m(ctx, reach, limit)
    left = reach.energy_available_J - reach.energy_used_J
    swept = sweep_tour(ctx, setup, start, t0=0.0, optimise_speed=False)
    if swept is None:
        return
    route = _assert_home_to_home(swept, ctx)
    true_map, radius = ctx.world.true_map, ctx.world.keep_away_m
    lines = shapely.linestrings(np.stack([route[:-1], route[1:]], axis=1))
    assert shapely.covers(true_map.boundary.buffer(-radius + 1e-6), lines).all()
    if not true_map.keep_out.is_empty:
        assert (shapely.distance(true_map.keep_out, lines) >= radius - 1e-6).all()

    # each candidate scored under the rule the planner chose by (the closed loop's reserve)
    # over the budgets a run flies on (the a-priori run-to-run discrepancy)
    flown, run_sd = _closed_loop(ctx), ctx.model.discrepancy_rel_sd
    scores = _every_sweep_joined(flown, setup, home, detours, lanes, left, limit, max_m, run_sd)
    lawn = plan_lawnmower(ctx, reach, lanes=lanes).xy_m
    base = _spread(flown, setup, home, lawn, left, limit, max_m, run_sd)
    planned = np.array([m2 for _, m2 in swept.summary["closed_loop_spread_m2"]])
    assert np.all(planned >= base - 1e-6), (planned, base)
    as_good = [sc for sc in scores if np.all(sc >= base - 1e-6)]
    assert not as_good or planned.mean() >= max(sc.mean() for sc in as_good) - 1e-6
