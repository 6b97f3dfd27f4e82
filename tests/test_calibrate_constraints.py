"""Physical constraints in calibration: every fitted coefficient stays in its
physical range, a coefficient the data cannot pin is held at its prior with the prior's
uncertainty, and one the data pin beyond its range sits on the bound, reported.

The synthetic cases build the samples by hand (features written out here, not taken from the
model) so the expected values come from an independent least-squares solve."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli, write_scenario
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from orange_plan.context import load_context
from orange_plan.identify.calibrate import Calibrator, Samples
from orange_plan.physics.model_builder import model_with_terms
from orange_plan.physics.state import MotionState
from orange_plan.telemetry.importers import read_log
from orange_plan.telemetry.recording import write_recording

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
G = 9.81
CRR = 0.05
PHYSICAL = {"regen_efficiency": (0.0, 1.0)}
"""Physical range of each coefficient, written out here: [0, inf) unless listed."""


def samples(state: MotionState, power_W: np.ndarray, dt_s: float = 0.1) -> Samples:
    """One recording's samples in 10 equal time blocks (as ``recording_samples`` labels them)."""
    n = power_W.size
    block = np.stack([np.zeros(n, int), np.arange(n) * 10 // n], axis=1)
    return Samples(state, power_W, np.full(n, dt_s), block, np.zeros(n, bool))


def scenario_ctx(tmp_path, **changes):
    return load_context(write_scenario(tmp_path, set=changes or None))


def driving(n: int, rng, yaw=False) -> MotionState:
    speed = rng.uniform(0.2, 1.5, n)
    yaw_rate = rng.uniform(-0.8, 0.8, n) if yaw else np.zeros(n)
    return MotionState(speed_mps=speed, crr=np.full(n, CRR), yaw_rate_radps=yaw_rate)


@pytest.mark.parametrize("turn_prior", [3.0, 0.0])
def test_absent_feature_is_held_at_its_prior_with_the_prior_sd(tmp_path, turn_prior):
    # no heading change in the data: the turning coefficient is not seen at all
    ctx = scenario_ctx(tmp_path, **{"robot.turn_coeff_W_s_per_rad": turn_prior})
    model = model_with_terms(ctx, ["ancillary", "rolling", "turning"])
    rng = np.random.default_rng(0)
    state = driving(3000, rng)
    power = 9.0 + 20.0 * CRR * G * state.speed_mps + rng.normal(0, 0.5, 3000)
    cal = Calibrator().fit_samples(samples(state, power), model)
    scenario_sd = model.stderr()["turn_J_per_rad"]
    assert cal.theta_["turn_J_per_rad"] == turn_prior
    # with a prior: its (widened) sd; without one: the scenario's, none
    assert cal.stderr_["turn_J_per_rad"] == pytest.approx(cal.prior_scale * scenario_sd)
    assert cal.fit_report_.held_at_prior == ("turn_J_per_rad",)
    assert cal.theta_["rolling_kg"] == pytest.approx(20.0, abs=3 * cal.stderr_["rolling_kg"])


def hand_features(state: MotionState) -> np.ndarray:
    """Columns ancillary, rolling (crr g v), drag (v^3 without wind) [W per coefficient]."""
    v = state.speed_mps
    return np.column_stack([np.ones_like(v), CRR * G * v, v**3])


def test_negative_least_squares_lands_on_the_bound_and_is_flagged(tmp_path):
    ctx = scenario_ctx(tmp_path)  # drag 0 in the scenario: no prior
    model = model_with_terms(ctx, ["ancillary", "rolling", "aero_drag"])
    rng = np.random.default_rng(1)
    state = driving(4000, rng)
    x = hand_features(state)
    power = x @ [9.0, 20.0, -1.5] + rng.normal(0, 0.3, 4000)  # less draw when fast
    plain = np.linalg.lstsq(x, power, rcond=None)[0]
    assert plain[2] < -1.0  # unconstrained least squares goes unphysical
    cal = Calibrator(use_prior=False).fit_samples(samples(state, power), model)
    assert cal.theta_["drag_kg_per_m"] == 0.0
    assert cal.fit_report_.clipped == ("drag_kg_per_m",)
    assert cal.fit_report_.held_at_prior == ()
    assert cal.fit_report_.unphysical == ()
    assert 0.0 < cal.stderr_["drag_kg_per_m"] < 0.1  # its own sd reported, not zero
    # the rest is the least-squares fit with drag on its bound
    rest = np.linalg.lstsq(x[:, :2], power, rcond=None)[0]
    assert cal.theta_["ancillary_W"] == pytest.approx(rest[0], rel=1e-6)
    assert cal.theta_["rolling_kg"] == pytest.approx(rest[1], rel=1e-6)


def test_a_prior_pulled_far_through_its_bound_is_held(tmp_path):
    # power falls with speed: a rolling coefficient would have to be about -30, which is
    # no rolling resistance at all; with a prior it stays there, the idle draw refitted
    ctx = scenario_ctx(tmp_path)
    model = model_with_terms(ctx, ["ancillary", "rolling"])
    rng = np.random.default_rng(2)
    state = driving(3000, rng)
    power = hand_features(state)[:, :2] @ [40.0, -30.0] + rng.normal(0, 0.5, 3000)
    cal = Calibrator().fit_samples(samples(state, power), model)
    prior = ctx.model.coefficient("rolling_kg")
    assert cal.fit_report_.held_at_prior == ("rolling_kg",)
    assert cal.theta_["rolling_kg"] == prior
    assert cal.stderr_["rolling_kg"] == pytest.approx(cal.prior_scale * ctx.model.stderr()["rolling_kg"])
    rolling_W = prior * CRR * G * state.speed_mps
    assert cal.theta_["ancillary_W"] == pytest.approx(np.mean(power - rolling_W), rel=1e-3)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(truth=st.tuples(*[st.floats(-50.0, 50.0)] * 4, st.floats(-2.0, 3.0)),
       noise_W=st.floats(0.01, 20.0), n=st.integers(40, 600), seed=st.integers(0, 2**16),
       use_prior=st.booleans())
def test_fitted_coefficients_always_lie_in_their_physical_range(tmp_path, truth, noise_W, n,
                                                                 seed, use_prior):
    ctx = scenario_ctx(tmp_path)
    model = model_with_terms(ctx, ["ancillary", "rolling", "aero_drag", "turning", "regen"])
    rng = np.random.default_rng(seed)
    grade = rng.uniform(-0.15, 0.15, n)  # descents give regen something to recover
    state = MotionState(speed_mps=rng.uniform(0.05, 2.0, n), cos_t=np.cos(grade),
                        sin_t=np.sin(grade), crr=np.full(n, CRR),
                        yaw_rate_radps=rng.uniform(-1.0, 1.0, n))
    # any truth, physical or not: power from the model's own terms plus noise
    power = np.asarray(model.with_theta(dict(zip(model.names, truth))).power_W(state), float)
    power = power + rng.normal(0, noise_W, n)
    cal = Calibrator(use_prior=use_prior).fit_samples(samples(state, power), model)
    fit = cal.fit_report_
    for name, value in cal.theta_.items():
        low, high = PHYSICAL.get(name, (0.0, np.inf))
        assert low <= value <= high, (name, value)
        assert np.isfinite(cal.stderr_[name]) and cal.stderr_[name] >= 0.0, name
    for name in fit.held_at_prior:
        assert cal.theta_[name] == pytest.approx(np.clip(cal.prior_[name], *PHYSICAL.get(name, (0.0, np.inf))))
    assert fit.unphysical == () and not set(fit.held_at_prior) & set(fit.clipped)


def convert(tmp_path: Path, run: str) -> Path:
    return write_recording(read_log(DATA / "borealtc" / "ASPHALT" / f"pro_{run}.csv")[0],
                           tmp_path / f"asphalt_{run}.csv")


@pytest.mark.skipif(not (DATA / "borealtc").is_dir(),
                    reason="real data not present in ../shared/data (BorealTC)")
@pytest.mark.parametrize("run", ["01", "02"])
def test_husky_run_calibrates_physically_and_predicts_other_runs(tmp_path, run):
    # one converted ASPHALT run, the scenario's whole model. Unconstrained, run 01 gave drag
    # -45749 kg/m and run 02 rolling -800 kg, and the written scenario predicted the other
    # ASPHALT runs at up to +5306 % (docs/guide/recordings.md, constraints measured)
    out = tmp_path / "fitted.toml"
    code, stdout, stderr = run_cli("calibrate", convert(tmp_path, run), "--scenario",
                                   REPO / "scenarios" / "husky_a200.toml", "-o", out, "--json")
    assert code == 0, stderr
    report = json.loads(stdout)
    fit = report["fit"]
    assert fit["unphysical"] == []
    assert all(v >= 0 for v in report["params"].values())
    # the speed-proportional rolling and the drag the scenario leaves off stay at 0
    assert report["params"]["rolling_kg"] == report["params"]["drag_kg_per_m"] == 0.0
    assert fit["held_at_prior"] and all(n in report["params"] for n in fit["held_at_prior"])
    assert "warning: held at the prior (the data cannot pin them): " in stderr
    assert len([line for line in stderr.splitlines() if "held at the prior" in line]) == 1
    for other in ("00", "03", "05"):
        code, stdout, stderr = run_cli("predict", convert(tmp_path, other), "--scenario", out,
                                       "--json")
        assert code == 0, stderr
        assert abs(json.loads(stdout)["energy_error_pct"]) < 60.0, other
