"""Online ORangE: recursive coefficient estimate and remaining range from streamed samples."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import write_scenario
from hypothesis import given, settings
from hypothesis import strategies as st

from orange_plan.bench.identify import online_run
from orange_plan.context import load_context
from orange_plan.errors import InputError
from orange_plan.identify.online import OnlineEstimator, stream
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.state import MotionState
from orange_plan.physics.terms import TERMS
from orange_plan.sim.ranges import accuracy_pct, offline_range_m
from orange_plan.sim.route import Route
from orange_plan.sim.simulator import simulate
from orange_plan.sim.truth import Truth
from orange_plan.telemetry.recording import recording_from_frame
from orange_plan.telemetry.state import recording_state

LOOP = np.array([[1.0, 1.0], [18.0, 1.0], [18.0, 4.0], [1.0, 4.0], [1.0, 1.0]])


@pytest.fixture
def ctx(tmp_path):
    return load_context(write_scenario(tmp_path))


def run(ctx, truth, seed=0):
    sim = simulate(ctx, Route(LOOP, np.full(5, 0.8), "loop"), truth, seed=seed, to_depletion=True)
    rec = recording_from_frame(sim.frame, "sim")
    return sim, rec, recording_state(rec, ctx.world, sensor_rate_Hz=ctx.conditions.sensor_rate_Hz)


def test_online_range_tracks_a_truth_the_offline_estimate_misses(ctx):
    """Rolling resistance 60 % above the scenario's: the a priori range is too long; after
    20 % of the run the online estimate has learnt it."""
    rolling = 1.6 * ctx.model.coefficient("rolling_kg")
    sim, rec, state = run(ctx, Truth(coefficients={"rolling_kg": rolling}, power_std_W=0.3))
    est = OnlineEstimator(ctx.model, ctx.scenario.battery.usable_J)
    history = stream(est, state, rec.frame["power_W"], rec.t_s, until_s=0.2 * sim.duration_s)
    last = history[-1]
    route = Route(LOOP, np.full(5, 0.8), "loop")
    offline = accuracy_pct(offline_range_m(ctx, route), sim.distance_m)
    online = accuracy_pct(last.range_total_m, sim.distance_m)
    assert online > 97.0 and online > offline + 3.0
    assert last.theta["rolling_kg"] == pytest.approx(rolling, rel=0.05)
    assert last.energy_used_J == pytest.approx(np.sum(rec.frame["power_W"][: int(
        last.t_s * 10)]) * 0.1, rel=1e-3)
    assert last.energy_remaining_J == pytest.approx(ctx.scenario.battery.usable_J - last.energy_used_J)
    assert 0 < last.range_remaining_sd_m < 0.05 * last.range_remaining_m
    # the route-ahead mode (planned path costed with the live coefficients) agrees
    from orange_plan.physics.pathcost import segments_energy_jacobian, subdivide

    steps = subdivide(ctx.world, LOOP[:-1], LOOP[1:])
    jac = segments_energy_jacobian(ctx.model, ctx.world, steps, 0.8,
                                   ctx.conditions).sum(axis=0)
    ahead = est.estimate(jac, route.length_m)
    assert accuracy_pct(ahead.range_total_m, sim.distance_m) > 95.0


def test_forgetting_follows_a_payload_change(ctx):
    truth = Truth(payload_kg=20.0, payload_from_s=600.0, power_std_W=0.2)
    _sim, rec, state = run(ctx, truth, seed=1)
    slow = OnlineEstimator(ctx.model, ctx.scenario.battery.usable_J, memory_s=1e6)
    fast = OnlineEstimator(ctx.model, ctx.scenario.battery.usable_J, memory_s=120.0)
    for est in (slow, fast):
        stream(est, state, rec.frame["power_W"], rec.t_s, until_s=1500.0)
    heavier = ctx.model.coefficient("rolling_kg") * 3.0  # (10 + 20) / 10
    err_fast = abs(fast.estimate().theta["rolling_kg"] - heavier)
    err_slow = abs(slow.estimate().theta["rolling_kg"] - heavier)
    assert err_fast < 0.05 * heavier < err_slow


def test_coefficients_the_data_cannot_see_stay_at_the_prior(ctx):
    _sim, rec, state = run(ctx, Truth(power_std_W=0.2))
    est = OnlineEstimator(ctx.model, ctx.scenario.battery.usable_J)
    last = stream(est, state, rec.frame["power_W"], rec.t_s, until_s=300.0)[-1]
    assert last.theta["grade_kg"] == pytest.approx(ctx.model.coefficient("grade_kg"))  # flat yard
    assert last.stderr["grade_kg"] == pytest.approx(ctx.model.stderr()["grade_kg"], rel=1e-6)


def test_bad_input_is_refused(ctx):
    with pytest.raises(InputError, match="memory_s = 0 must be a positive number"):
        OnlineEstimator(ctx.model, 1000.0, memory_s=0)
    est = OnlineEstimator(ctx.model, 1000.0)
    with pytest.raises(InputError, match="finite power and dt_s >= 0"):
        est.update(MotionState(speed_mps=np.ones(2)), [1.0, np.nan], 0.1)
    with pytest.raises(InputError, match="route_length_m must be > 0"):
        est.estimate(np.ones(len(ctx.model.names)), 0.0)


SIMPLE = EnergyModel([TERMS["ancillary"], TERMS["rolling"]], {"ancillary_W": 5.0, "rolling_kg": 10.0},
                     np.diag([1.0, 4.0]))


@settings(max_examples=60, deadline=None)
@given(power=st.lists(st.floats(-50, 200), min_size=2, max_size=30),
       speed=st.floats(0.0, 3.0), energy=st.floats(1.0, 1e5), memory=st.floats(1.0, 1e4))
def test_remaining_range_is_never_negative(power, speed, energy, memory):
    est = OnlineEstimator(SIMPLE, energy, memory_s=memory, window_s=5.0)
    n = len(power)
    state = MotionState(speed_mps=np.full(n, speed), crr=np.full(n, 0.05))
    for k in range(0, n, 3):
        e = est.update(state.with_(speed_mps=state.speed_mps[k:k + 3], crr=state.crr[k:k + 3]),
                       power[k:k + 3], 0.5)
        assert e.energy_remaining_J >= 0.0
        assert not (e.range_remaining_m < 0.0)
        assert not (e.range_total_m < e.distance_m)
        assert math.isfinite(e.energy_used_J)


@settings(max_examples=60, deadline=None)
@given(power=st.lists(st.floats(-2000, 200), min_size=1, max_size=30),
       dt=st.floats(0.01, 10.0), energy=st.floats(1.0, 1e5))
def test_regeneration_refills_the_battery_at_most_to_full(power, dt, energy):
    """Energy used is sum P dt held at 0 from below, sample by sample (a full battery takes
    no more), so the energy left never exceeds the battery's."""
    est = OnlineEstimator(SIMPLE, energy, window_s=5.0)
    n = len(power)
    state = MotionState(speed_mps=np.full(n, 0.5), crr=np.full(n, 0.05))
    used = 0.0
    for k in range(0, n, 3):
        e = est.update(state.with_(speed_mps=state.speed_mps[k:k + 3], crr=state.crr[k:k + 3]),
                       power[k:k + 3], dt)
        for p in power[k:k + 3]:
            used = max(0.0, used + p * dt)
        assert e.energy_used_J >= 0.0
        assert e.energy_used_J == pytest.approx(used, rel=1e-9, abs=1e-6)
        assert e.energy_remaining_J <= energy


@pytest.mark.parametrize("name", ["rusti_v1_box"])
def test_bench_run_on_a_repo_scenario(name):
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    ctx = load_context(repo / "scenarios" / f"{name}.toml")
    row = online_run(ctx, {"coefficients": {"rolling_kg": 5.4}}, seed=0, predict_at=(0.2,))
    assert row.accuracy_online_pct > 97.0
    assert row.accuracy_online_pct > row.accuracy_offline_pct


def test_online_whole_run_energy_beats_the_offline_model_on_a_wrong_prior(ctx):
    """Whole-run energy (the real-recording comparison of `bench calibration`): with rolling
    60 % above the scenario's, the a-priori model under-predicts the run; measured energy so
    far plus the live coefficients on the motion ahead is within 2 % from 20 % of the run."""
    from orange_plan.bench.identify import online_energy_errors, whole_run_energy_J

    rolling = 1.6 * ctx.model.coefficient("rolling_kg")
    _, rec, _ = run(ctx, Truth(coefficients={"rolling_kg": rolling}, power_std_W=0.3))
    offline = 100 * (whole_run_energy_J(ctx.model, rec, ctx, {}) / rec.energy_J - 1)
    online = online_energy_errors(ctx.model, rec, ctx, {}, fractions=(0.2, 0.6))
    assert offline < -10.0                                  # the prior misses the rolling
    assert len(online) == 2 and max(abs(e) for e in online) < 2.0
    # with the true model, nothing is left to learn: online = offline = recorded (noise only)
    exact = ctx.model.with_theta({"rolling_kg": rolling})
    assert all(abs(e) < 0.5 for e in online_energy_errors(exact, rec, ctx, {}, (0.2,)))


def test_online_energy_per_metre_with_regen_is_the_modelled_energy():
    """Regen is bilinear in theta, so H.theta alone would count recovered power twice: on a
    downhill stretch the live energy per metre must equal the model's power integral."""
    model = EnergyModel([TERMS["ancillary"], TERMS["rolling"], TERMS["grade"], TERMS["regen"]],
                        {"ancillary_W": 10.0, "rolling_kg": 20.0, "grade_kg": 20.0,
                         "regen_efficiency": 0.5}, omega=0.8)
    n = 40
    sin_t = np.where(np.arange(n) % 2, -0.2, 0.1)          # alternating up and down 1 m/s
    state = MotionState(speed_mps=np.ones(n), sin_t=sin_t, cos_t=np.sqrt(1 - sin_t**2),
                        crr=np.full(n, 0.02))
    power = np.asarray(model.power_W(state), float)
    assert power.min() < 0                                  # regen recovers downhill
    est = OnlineEstimator(model, 1e6, memory_s=1e6, window_s=1e6)
    last = est.update(state, power, 1.0)                    # exact data: theta stays put
    expected = float(power.sum()) / n                       # [J/m] at 1 m/s, dt = 1 s
    assert last.energy_per_m_J == pytest.approx(expected, rel=1e-6)
