"""planning.lawnmower (the boustrophedon baseline) and bench.px4_rtl (PX4's return rule)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from planning_worlds import write_world

from orange_plan.bench.px4_rtl import (
    RTL_TIME_FACTOR,
    RTL_TIME_MARGIN_S,
    HomePaths,
    ReturnRule,
    decide_return,
    flown_route,
    locate_on_path,
)
from orange_plan.context import load_context
from orange_plan.errors import InputError
from orange_plan.planning.coverage import coverage_grid, footprint
from orange_plan.planning.lawnmower import boustrophedon, plan_lawnmower, sweep_lanes
from orange_plan.planning.reach import prepare_reach
from orange_plan.sim.route import Route
from orange_plan.sim.simulator import simulate

pytestmark = pytest.mark.timeout(60)


@pytest.fixture(scope="module")
def open_field(tmp_path_factory):
    ctx = load_context(write_world(tmp_path_factory.mktemp("open"), width_m=40, height_m=30,
                                   home=(2.0, 2.0), name="open"))
    return ctx, prepare_reach(ctx, n_vertices=300)


@pytest.fixture(scope="module")
def yard(tmp_path_factory):
    ctx = load_context(write_world(tmp_path_factory.mktemp("yard"), width_m=40, height_m=30,
                                   obstacles=[(10, 4, 14, 26), (24, 0, 28, 12), (24, 18, 28, 30)],
                                   hill=(20.0, 15.0, 4.0, 6.0), home=(2.0, 2.0), name="yard"))
    return ctx, prepare_reach(ctx, n_vertices=400)


def _starts_and_ends_home(ctx, xy):
    assert np.allclose(xy[0], ctx.world.home_xy_m) and np.allclose(xy[-1], ctx.world.home_xy_m)


@pytest.mark.parametrize("angle", [None, 0.0, 35.0, 90.0])
def test_open_rectangle_is_covered_from_home_to_home(open_field, angle):
    ctx, reach = open_field
    lawn = plan_lawnmower(ctx, reach, angle_deg=angle)
    _starts_and_ends_home(ctx, lawn.xy_m)
    assert ctx.world.segments_free(lawn.xy_m[:-1], lawn.xy_m[1:]).all()
    covered = footprint(ctx.world, lawn.xy_m, ctx.scenario.mission.sensor_radius_m).area
    assert covered >= 0.90 * ctx.world.map.free_space.area
    assert lawn.spacing_m == 2 * ctx.scenario.mission.sensor_radius_m
    assert lawn.speed_mps == pytest.approx(ctx.cruise_speed_mps)


def test_obstacles_are_avoided_by_detours(yard):
    ctx, reach = yard
    lawn = plan_lawnmower(ctx, reach, angle_deg=90.0)
    _starts_and_ends_home(ctx, lawn.xy_m)
    assert ctx.world.segments_free(lawn.xy_m[:-1], lawn.xy_m[1:]).all()
    assert lawn.n_detours > 0
    covered = footprint(ctx.world, lawn.xy_m, ctx.scenario.mission.sensor_radius_m).area
    assert covered >= 0.85 * ctx.world.map.free_space.area


def test_lanes_are_at_most_two_radii_apart_and_alternate(tmp_path):
    ctx = load_context(write_world(tmp_path, width_m=20, height_m=8, obstacles=[(8, 0, 12, 3)],
                                   home=(2.0, 6.0)))  # r = 1 m: four lanes, the first split
    grid = coverage_grid(ctx.world, 1.0)
    lanes = sweep_lanes(ctx.world, grid, 1.0, 0.0)
    y = [lane[0][0, 1] for lane in lanes]
    assert np.allclose(y, [1.0, 3.0, 5.0, 7.0])
    assert len(lanes[0]) == 2 and lanes[0][0][1, 0] < lanes[0][1][0, 0]  # split, west first
    order = boustrophedon(lanes)
    assert order[0][1, 0] > order[0][0, 0]  # lane 0 eastwards
    assert order[2][1, 0] < order[2][0, 0] and order[2][0, 1] == pytest.approx(3.0)  # back west
    other_side = sweep_lanes(ctx.world, grid, 1.0, 180.0)  # same lanes, swept from the north
    assert [lane[0][0, 1] for lane in other_side] == y[::-1]
    north = sweep_lanes(ctx.world, grid, 1.0, 90.0)
    d = north[0][0][1] - north[0][0][0]
    assert abs(d[0]) < 1e-9 and d[1] > 0  # lanes run north at 90 deg


def test_joined_path_marks_its_lanes(yard):
    from orange_plan.planning.lawnmower import Detours, join_pieces

    ctx, reach = yard
    r = ctx.scenario.mission.sensor_radius_m
    pieces = boustrophedon(sweep_lanes(ctx.world, coverage_grid(ctx.world, r), r, 90.0))
    rm = reach.roadmap
    xy, lane, driven, _ = join_pieces(ctx.world.home_xy_m, pieces,
                                      Detours(ctx.world, rm.xy_m, rm.src, rm.dst))
    seg = np.hypot(*np.diff(xy, axis=0).T)
    assert lane.shape == seg.shape and driven == len(pieces)
    assert seg[lane].sum() == pytest.approx(sum(np.hypot(*(p[1] - p[0])) for p in pieces))


class _NoWayHomeFrom:
    """A roadmap that finds no way home from the given points (a lane's end hemmed in by
    walls) and the straight line from anywhere else."""

    def __init__(self, blocked):
        self.blocked = [np.asarray(b, float) for b in blocked]

    def segments_free(self, a, b):
        return np.ones(len(np.atleast_2d(a)), bool)

    def path(self, a, b):
        if any(np.allclose(a, x) for x in self.blocked):
            return None
        return np.array([a, b], float)


def test_a_lane_end_with_no_roadmap_way_home_drives_back_along_the_route():
    """The last piece ends where the roadmap finds no way home: the route goes back along
    itself to the latest vertex with one, and still ends at home."""
    from orange_plan.planning.lawnmower import join_pieces

    home = np.array([0.0, 0.0])
    pieces = [np.array([[1.0, 0.0], [1.0, 5.0]]), np.array([[2.0, 5.0], [2.0, 0.0]])]
    xy, lane, driven, _ = join_pieces(home, pieces, _NoWayHomeFrom([[2.0, 0.0], [2.0, 5.0]]))
    assert driven == 2 and np.allclose(xy[0], home) and np.allclose(xy[-1], home)
    # back over the second lane and the join, then the roadmap's way from the first's end
    assert np.allclose(xy[-4:], [[2.0, 0.0], [2.0, 5.0], [1.0, 5.0], home])
    assert lane.shape == (len(xy) - 1,) and lane.sum() == 2
    # nowhere a way home but from home itself: the whole route backwards
    xy, _, _, _ = join_pieces(home, pieces, _NoWayHomeFrom([[2.0, 0.0], [2.0, 5.0],
                                                            [1.0, 5.0], [1.0, 0.0]]))
    assert np.allclose(xy[-1], home) and len(xy) == 9


def test_best_angle_runs_along_the_long_side(tmp_path):
    ctx = load_context(write_world(tmp_path, width_m=60, height_m=12, home=(2.0, 2.0)))
    lawn = plan_lawnmower(ctx, prepare_reach(ctx, n_vertices=200))
    assert min(lawn.angle_deg % 180, 180 - lawn.angle_deg % 180) <= 10.0


# --- the PX4 rule ----------------------------------------------------------------------------


def test_rule_fires_exactly_when_its_inequality_first_holds():
    # 1 Hz trace: constant 10 W, 2000 J usable, flying away from home at 0.5 s of return per s.
    t = np.arange(0.0, 150.0)
    power = np.full(t.size, 10.0)
    used = 10.0 * t
    time_home = 0.5 * t
    rule = ReturnRule()
    avg = rule.average_power_W(t, power, initial_W=10.0)
    assert np.allclose(avg, 10.0)
    i = rule.first_return_index(t, used, avg, time_home, 2000.0)
    # 1.1 * 0.5 t + 100 >= (2000 - 10 t) / 10  <=>  t >= 100 / 1.55 = 64.5
    assert i == 65
    lhs = RTL_TIME_FACTOR * time_home + RTL_TIME_MARGIN_S
    rhs = (2000.0 - used) / avg
    assert lhs[i] >= rhs[i] and (lhs[:i] < rhs[:i]).all()
    # the time limit look-ahead: t + 1.1 * 0.5 t + 100 >= 150  <=>  t >= 32.3
    assert rule.first_return_index(t, used, avg, time_home, 2000.0, time_limit_s=150.0) == 33
    assert rule.first_return_index(t, used, avg, 0 * t, 1e9) is None


def test_average_power_is_px4s_first_order_filter():
    rule = ReturnRule(power_tau_s=9.0)
    t = np.array([0.0, 1.0, 2.0])
    # a = dt / (tau + dt) = 0.1: y0 = 10 + 0.1 (20 - 10) = 11, y1 = 11 + 0.1 (20 - 11) = 11.9
    assert np.allclose(rule.average_power_W(t, [20.0, 20.0, 20.0], 10.0), [11.0, 11.9, 12.71])
    mean = ReturnRule(power_tau_s=math.inf).average_power_W(t, [1.0, 3.0, 5.0], 0.0)
    assert np.allclose(mean, [1.0, 2.0, 3.0])
    with pytest.raises(InputError, match="time_factor"):
        ReturnRule(time_factor=0.9)
    with pytest.raises(InputError, match="time_margin_s"):
        ReturnRule(time_margin_s=-1.0)


def test_home_paths_return_to_home_through_free_space(yard):
    ctx, reach = yard
    home = HomePaths(reach)
    for p in [(20.0, 28.0), (38.0, 15.0), (16.0, 2.0)]:
        path = home.path(p)
        assert np.allclose(path[0], p) and np.allclose(path[-1], ctx.world.home_xy_m)
        assert ctx.world.segments_free(path[:-1], path[1:]).all()
        length = float(np.sum(np.hypot(*np.diff(path, axis=0).T)))
        assert home.length_m([p])[0] == pytest.approx(length, rel=1e-9)
        assert home.time_s([p])[0] == pytest.approx(length / reach.exact.speed_mps)


def test_decision_on_a_simulated_lawnmower_and_the_flown_route(yard):
    ctx, reach = yard
    lawn = plan_lawnmower(ctx, reach, angle_deg=0.0)
    home = HomePaths(reach)
    sim = simulate(ctx, Route(lawn.xy_m, np.full(len(lawn.xy_m), np.nan), "lawn"))
    tight = ReturnRule(time_margin_s=0.0)
    usable = ctx.scenario.battery.usable_J
    decision = decide_return(ctx, sim.frame, lawn.xy_m, home, tight)
    # 1 Wh does not drive the whole lawnmower: the rule fires, where the recording says
    assert sim.energy_J > usable and decision.fired
    k = int(np.searchsorted(sim.frame["t_s"].to_numpy(), decision.t_s))
    assert np.allclose(sim.frame[["x_m", "y_m"]].to_numpy()[k], decision.xy_m)
    assert decision.time_home_s * RTL_TIME_FACTOR >= decision.time_left_s - 1e-6
    route = flown_route(lawn.xy_m, decision, home)
    _starts_and_ends_home(ctx, route)
    assert ctx.world.segments_free(route[:-1], route[1:]).all()
    assert locate_on_path(lawn.xy_m, decision.xy_m, decision.s_m) == pytest.approx(
        decision.s_m, abs=1e-6)
