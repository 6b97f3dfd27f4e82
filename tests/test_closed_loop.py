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
    if out["returned_early"]:  # the return is recorded: what was predicted, kept and flown
        assert out["return_predicted_J"] > 0 and out["return_flown_J"] > 0
        assert out["return_reserve_J"] >= 0


def test_a_closed_loop_keeps_the_models_spread_for_the_way_home():
    """Past the guaranteed extent the way home is never taken as better known than the floor's
    share of the model's run-to-run discrepancy:
    reserve >= z_p * RETURN_SPREAD_FLOOR * discrepancy * E_home."""
    from scipy.special import ndtri

    from orange_plan.planning.reserve import RETURN_SPREAD_FLOOR
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
    floor = RETURN_SPREAD_FLOOR * kit.ctx.model.discrepancy_rel_sd
    assert d.reserve_J >= z * floor * d.energy_to_home_J - 1e-6


def test_the_session_names_the_way_home_it_costs():
    from orange_plan.planning.session import MissionSession

    spec = mission_specs(1, n_maps=1, width_m=60.0, height_m=45.0, n_vertices=300)[0]
    kit = map_kit(spec)
    session = MissionSession(kit.ctx, kit.plan, n_vertices=300)
    back = session.way_home_xy_m()
    assert np.allclose(back[-1], kit.ctx.world.home_xy_m)
    assert kit.ctx.world.segments_free(back[:-1], back[1:]).all()


def _closed_loop_session(batches: int):
    """A closed-loop session on a small sweep plan with a battery four times the plan's (room
    to spare), fed ``batches`` 10 s batches of the simulated route (the study's telemetry
    rate)."""
    from dataclasses import replace

    from orange_plan.planning.session import MissionSession
    from orange_plan.sim.flight import simulate_route as _simulate

    spec = mission_specs(1, n_maps=1, width_m=60.0, height_m=45.0, n_vertices=300)[0]
    kit = map_kit(spec)
    sc = kit.ctx.scenario
    big = replace(sc.battery, rated_energy_Wh=4.0 * sc.battery.rated_energy_Wh)
    ctx = kit.ctx.with_scenario(replace(sc, battery=big))
    session = MissionSession(ctx, kit.plan, n_vertices=300, closed_loop=True)
    frame = _simulate(ctx, session.route_xy_m, session.route_speed_mps, None, 0, 5.0).frame
    for a in range(0, 50 * batches, 50):
        session.feed(frame.iloc[a:a + 50][["t_s", "power_W", "x_m", "y_m"]])
    return kit, session


def _distance_to_polyline(p, xy) -> float:
    a, b = xy[:-1], xy[1:]
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab),
                                                                 1e-18), 0, 1)
    return float(np.min(np.hypot(*(p - (a + t[:, None] * ab)).T)))


def test_with_energy_to_spare_the_homeward_route_flies_the_stretch_ahead_first():
    """Told home with a wide margin, the robot first flies the whole stretch the live check
    looked at (the next batch's route), then the way home from its end."""
    kit, session = _closed_loop_session(batches=2)
    ahead, _ = session._route_ahead()
    back = session.homeward_xy_m()
    assert np.allclose(back[0], session.position_xy_m)
    assert np.allclose(back[-1], kit.ctx.world.home_xy_m)
    assert kit.ctx.world.segments_free(back[:-1], back[1:]).all()
    k = int(np.flatnonzero(np.hypot(*(back - ahead[-1]).T) < 1e-9)[0])
    assert all(_distance_to_polyline(p, ahead) < 1e-6 for p in back[:k + 1])
    assert np.allclose(back[k:], session._way_home_from(ahead[-1]))


def test_with_no_energy_to_spare_the_homeward_route_is_the_way_home():
    """A margin already spent leaves nothing for the stretch ahead: straight home."""
    _, session = _closed_loop_session(batches=2)
    x, y = session.position_xy_m
    left = session.energy_available_J - session.energy_used_J
    d = session.feed([{"t_s": session.time_s + 1.0, "power_W": left - 1.0, "x_m": x,
                       "y_m": y}])
    assert d.action == "return_home" and d.homing_margin_J < 0
    assert np.allclose(session.homeward_xy_m(), session.way_home_xy_m())


def test_the_homeward_route_ends_where_the_margin_is_spent():
    """Cut where the stretch, the way home from its end and the reserve for both fit: the
    longest cut that fits is taken, no longer one (the way home may shrink along the
    stretch, so fitting need not be monotone)."""
    from orange_plan.planning.paths import cut_path
    from orange_plan.planning.session.facade import HOMEWARD_CUTS

    _, session = _closed_loop_session(batches=2)
    ahead, speeds = session._route_ahead()
    length = float(np.sum(np.hypot(*np.diff(ahead, axis=0).T)))
    cuts = [cut_path(ahead, share * length)
            for share in np.arange(1, HOMEWARD_CUTS + 1) / HOMEWARD_CUTS]
    needs = [session._homeward_need_J(part, speeds) for part in cuts]
    # as if the battery held a joule less than the whole stretch needs (the energy alone: a
    # batch would also teach the estimator)
    session._intake.energy_used_J = session.energy_available_J - needs[-1] + 1.0
    spare = session.energy_available_J - session.energy_used_J
    back = session.homeward_xy_m()
    taken = [i for i, part in enumerate(cuts)
             if np.hypot(*(back - part[-1]).T).min() < 1e-9 and needs[i] <= spare]
    fitting = [i for i, need in enumerate(needs) if need <= spare]
    assert needs[-1] > spare and (HOMEWARD_CUTS - 1) not in taken
    assert max(taken, default=None) == max(fitting, default=None)


def test_the_sweep_is_chosen_under_the_closed_loops_return_reserve(monkeypatch, tmp_path):
    """The plan's sweep is chosen by what it senses under the rule that flies it: the closed
    loop keeps the floor of the a-priori discrepancy for its way home, not all of it; the
    plan's own checks keep the scenario's model."""
    from orange_plan.bench.mission import study_scenario
    from orange_plan.context import load_context
    from orange_plan.planning import sweeps
    from orange_plan.planning.reserve import RETURN_SPREAD_FLOOR
    from orange_plan.planning.tour import plan_tour

    seen = []
    real = sweeps.best_sweep

    def spy(ctx, *args, **kwargs):
        seen.append(ctx.model.discrepancy_rel_sd)
        return real(ctx, *args, **kwargs)

    monkeypatch.setattr(sweeps, "best_sweep", spy)
    spec = mission_specs(1, n_maps=1, width_m=60.0, height_m=45.0, n_vertices=300)[0]
    ctx = load_context(study_scenario(tmp_path, spec))
    plan = plan_tour(ctx, n_vertices=300, seed=0, bitstar_legs=0)
    assert seen == [pytest.approx(RETURN_SPREAD_FLOOR * ctx.model.discrepancy_rel_sd)]
    assert plan.margin_J.min() >= 0


def test_a_stretch_that_leaves_the_free_space_is_not_flown_home(monkeypatch):
    """The stretch starts at the reported position, off the route by the tracking error: where
    its join to the route is not free, the robot goes straight home by the checked way."""
    _, session = _closed_loop_session(batches=2)
    ahead, _ = session._route_ahead()
    here = np.asarray(session.position_xy_m)
    world = session.ctx.world
    real = type(world).segments_free

    def blocked_from_here_along_the_stretch(self, a, b):
        # as if an obstacle stood between the position and the route ahead (the ways home
        # from the position, joined to the roadmap, stay free)
        a, b = np.atleast_2d(a), np.atleast_2d(b)
        onto = np.array([_distance_to_polyline(p, ahead) < 1e-6 for p in b])
        return real(self, a, b) & ~(np.all(np.isclose(a, here), axis=1) & onto)

    monkeypatch.setattr(type(world), "segments_free", blocked_from_here_along_the_stretch)
    back = session.homeward_xy_m()
    way = session.way_home_xy_m()
    assert back.shape == way.shape and np.allclose(back, way)


def test_the_look_ahead_is_the_most_any_cut_of_the_stretch_needs():
    """The look-ahead weighs every cut of the next stretch: the stretch so far, the way home
    from there and the reserve for both, beyond what the way home needs now, and never less
    than the last batch drew; a crest inside the stretch counts."""
    _, session = _closed_loop_session(batches=2)
    home = session._return_home()
    now = home.energy_J + home.reserve_J
    ahead, _ = session._route_ahead()
    n = len(session._stretch_cuts(ahead))
    assert n == 8

    def needs_of(profile):
        lengths = [float(np.sum(np.hypot(*np.diff(p, axis=0).T)))
                   for p in session._stretch_cuts(ahead)]
        table = dict(zip(lengths, profile))
        return lambda part, speeds: table[float(np.sum(np.hypot(*np.diff(part, axis=0).T)))]

    last = session._intake.last_batch_J
    assert last > 0
    crest = [now + last + 10.0 * k for k in (1, 2, 3, 9, 4, 3, 2, 1)]  # dearest half way
    session._homeward_need_J = needs_of(crest)
    assert session._lookahead_J(home) == pytest.approx(last + 90.0)
    # every cut cheaper than turning now: still the last batch's draw (the stretch may be
    # costed short; the batch will draw about what the last one did)
    downhill = [now - 5.0 * k for k in range(1, 9)]
    session._homeward_need_J = needs_of(downhill)
    assert session._lookahead_J(home) == pytest.approx(last)
    blocked = [now + 1.0] * 7 + [math.inf]  # no way home from the stretch's end
    session._homeward_need_J = needs_of(blocked)
    assert session._lookahead_J(home) == math.inf
