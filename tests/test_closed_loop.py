"""The closed loop: a plan's continuation flown past the guaranteed extent, turned home on the
live check (MissionSession), with the next decision's look-ahead; the plan file keeps the
continuation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from orange_plan.bench.mission import fly_session, map_kit, mission_specs, mission_truth
from orange_plan.planning.plan import Plan
from orange_plan.planning.reserve import EnergyReserve
from orange_plan.planning.session import plan_from_geojson
from orange_plan.planning.session.decision import Home, HomingState, decide


def _plan(continuation=None, summary=None):
    xy = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 5.0], [0.0, 0.0]])
    n = len(xy)
    return Plan(xy, np.arange(n, dtype=float), np.full(n, 1.0), np.linspace(0, 30, n),
                np.full(n, 5.0), np.full(n, 1.0), np.full(n, 10.0), np.empty((0, 2)), None,
                summary or {}, continuation)


def test_closed_loop_route_is_the_tour_to_its_turn_then_the_continuation():
    rest = np.array([[10.0, 5.0], [20.0, 5.0], [20.0, 0.0], [0.0, 0.0]])
    route, speed, turn = _plan(rest, {"closed_loop_speed_mps": 2.0}).closed_loop_route()
    assert turn == 2
    assert np.allclose(route, [[0, 0], [10, 0], [10, 5], [20, 5], [20, 0], [0, 0]])
    assert np.allclose(speed, [1, 1, 1, 2, 2, 2])


def test_a_plan_without_a_continuation_is_its_own_route():
    plan = _plan()
    route, _, turn = plan.closed_loop_route()
    assert np.allclose(route, plan.xy_m) and turn == len(route) - 1
    assert plan.expected_continuation_xy_m() is None


def test_the_expected_continuation_stops_at_the_closed_loop_turn():
    rest = np.array([[10.0, 5.0], [20.0, 5.0], [20.0, 0.0], [0.0, 0.0]])
    plan = _plan(rest, {"guaranteed_length_m": 15.0, "closed_loop_turn_m": 27.0})
    assert np.allclose(plan.expected_continuation_xy_m(), [[10, 5], [20, 5], [20, 3]])


def test_the_plan_file_keeps_the_continuation():
    rest = np.array([[10.0, 5.0], [20.0, 5.0], [0.0, 0.0]])
    back = plan_from_geojson(_plan(rest).to_geojson())
    assert np.allclose(back.continuation_xy_m, rest)
    assert plan_from_geojson(_plan().to_geojson()).continuation_xy_m is None


def _state(margin_J: float, lookahead_J: float) -> HomingState:
    # 1000 J available, 500 used, home 300 + reserve 200 - margin
    home = Home(300.0, 200.0 - margin_J, 10.0)
    return HomingState((1.0, 1.0), 10.0, 500.0, 1000.0, 0.0, "free", EnergyReserve(0.0), home,
                       5.0, False, None, math.nan, 0.0, lookahead_J)


@pytest.mark.parametrize("margin, ahead, action", [(100.0, 150.0, "return_home"),
                                                    (100.0, 50.0, "continue"),
                                                    (100.0, 0.0, "continue"),
                                                    (-1.0, 0.0, "return_home")])
def test_the_return_is_decided_while_the_margin_covers_the_next_batch(margin, ahead, action):
    d = decide(_state(margin, ahead))
    assert d.action == action
    assert d.homing_margin_J == pytest.approx(margin)  # the reported margin is the plain one


@pytest.mark.timeout(280)
@settings(max_examples=3, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(map_seed=st.integers(0, 50), seed=st.integers(0, 50))
def test_closed_loop_missions_end_at_home_within_the_battery(map_seed, seed):
    """Missions flown by the session past the guaranteed extent of a sweep plan, under truths
    within the calibration uncertainty, turn home in time and end at home."""
    spec = mission_specs(1, n_maps=1, width_m=60.0, height_m=45.0, n_vertices=300)[0]
    spec = type(spec)(**{**spec.__dict__, "map_seed": map_seed})
    kit = map_kit(spec)
    if kit.plan is None:
        return
    truth, _ = mission_truth(kit.ctx, spec, seed)
    out = fly_session(kit, spec, truth, seed)
    assert not out["stranded"], out
    assert out["energy_left_J"] >= 0


def test_a_closed_loop_keeps_the_models_spread_for_the_way_home():
    """Past the guaranteed extent the way home is never taken as better known than the
    model's run-to-run discrepancy: reserve >= z_p * discrepancy * E_home."""
    from scipy.special import ndtri

    from orange_plan.planning.session import MissionSession
    from orange_plan.sim.flight import simulate_route as _simulate

    spec = mission_specs(1, n_maps=1, width_m=60.0, height_m=45.0, n_vertices=300)[0]
    kit = map_kit(spec)
    session = MissionSession(kit.ctx, kit.plan, n_vertices=300)
    if not session.closed_loop:
        pytest.skip("the first plan of this map is not a sweep with a continuation")
    frame = _simulate(kit.ctx, session.route_xy_m, session.route_speed_mps, None, 0, 5.0).frame
    d = session.feed(frame.iloc[:100][["t_s", "power_W", "x_m", "y_m"]])
    z = float(ndtri(kit.ctx.scenario.mission.reserve.value))
    assert d.reserve_J >= z * kit.ctx.model.discrepancy_rel_sd * d.energy_to_home_J - 1e-6


def test_the_session_names_the_way_home_it_costs():
    from orange_plan.planning.session import MissionSession

    spec = mission_specs(1, n_maps=1, width_m=60.0, height_m=45.0, n_vertices=300)[0]
    kit = map_kit(spec)
    session = MissionSession(kit.ctx, kit.plan, n_vertices=300)
    back = session.way_home_xy_m()
    assert np.allclose(back[-1], kit.ctx.world.home_xy_m)
    assert kit.ctx.world.segments_free(back[:-1], back[1:]).all()
