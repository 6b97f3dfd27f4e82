"""A drift of a coefficient: the rolling coefficient changing over mission time
(``physics.terms.drift_rolling_term``), in the model, the scenario, planning and diagnosis."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from orange_plan.errors import InputError
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.state import MotionState
from orange_plan.physics.terms import DRIFT_SHAPES, G_MPS2, TERMS, drift_rolling_term, spec_id

ROOT = Path(__file__).resolve().parents[1]
Z_MAX = 3.0


def _state(t, speed=2.0, crr=0.02, sin_t=0.0):
    t = np.asarray(t, float)
    return MotionState(speed_mps=speed + 0.0 * t, crr=crr, cos_t=np.sqrt(1 - sin_t**2),
                       sin_t=sin_t, channels={"elapsed_s": t})


def test_the_rolling_drift_power_by_hand():
    """Rolling 30 kg rising by 6 kg over 1000 s, at 2 m/s on crr 0.02: at t = 500 s the
    traction power is (30 + 6 * 0.5) * 9.81 * 0.02 * 2 W."""
    model = EnergyModel([TERMS["rolling"], drift_rolling_term("linear", 1000.0)],
                        {"rolling_kg": 30.0, "drift_rolling_kg": 6.0})
    power = model.power_W(_state([0.0, 500.0, 1000.0]))
    expected = np.array([30.0, 33.0, 36.0]) * G_MPS2 * 0.02 * 2.0
    assert np.asarray(power) == pytest.approx(expected, rel=1e-12)
    # a step of -9 kg at 600 s, a decay of +9 kg with 300 s, by hand
    step = EnergyModel([drift_rolling_term("step", 1.0, 600.0)], {"drift_rolling_kg": -9.0})
    assert float(step.traction_force_N(_state(700.0))) == pytest.approx(-9.0 * G_MPS2 * 0.02)
    decay = EnergyModel([drift_rolling_term("decay", 300.0)], {"drift_rolling_kg": 9.0})
    assert float(decay.traction_force_N(_state(300.0))) == pytest.approx(
        9.0 * np.exp(-1.0) * G_MPS2 * 0.02)


def test_a_rolling_drift_is_charged_through_the_traction_clip():
    """A force, not a power: on a descent steep enough that the net force is negative, a
    robot without regeneration is charged nothing, whatever the drift."""
    model = EnergyModel([TERMS["rolling"], TERMS["grade"], drift_rolling_term("linear", 100.0)],
                        {"rolling_kg": 30.0, "grade_kg": 30.0, "drift_rolling_kg": 5.0})
    assert float(model.power_W(_state(100.0, sin_t=-0.2))) == 0.0


@pytest.mark.parametrize("shape", DRIFT_SHAPES)
def test_the_rolling_drift_is_one_value_per_sample_numpy_and_casadi(shape):
    import casadi as ca

    term = drift_rolling_term(shape, 600.0, 900.0)
    t = np.array([0.0, 300.0, 899.0, 901.0, 3600.0])
    (phi,) = term.features(_state(t))
    assert np.asarray(phi).shape == t.shape
    scalar = term.features(MotionState(speed_mps=1.0, crr=0.02, channels={"elapsed_s": 1.0}))
    assert np.ndim(scalar[0]) == 0
    sym = ca.SX.sym("t")
    (expr,) = term.features(MotionState(speed_mps=1.0, crr=0.02, channels={"elapsed_s": sym}))
    f = ca.Function("f", [sym], [expr])
    assert [float(f(x)) for x in t] == pytest.approx(list(np.asarray(phi)), abs=1e-12)


def test_the_rolling_drift_is_a_variant_of_drift_and_the_vocabulary_one_decays():
    assert spec_id("drift_rolling") == "drift"
    assert TERMS["drift_rolling"].shape == ("decay", 1200.0, 0.0)
    assert TERMS["drift_rolling"].group == "force"


@pytest.mark.parametrize(("shape", "tau_s", "from_s"), [
    ("sine", 100.0, 0.0), ("linear", 0.0, 0.0), ("step", 100.0, -5.0),
    ("decay", float("nan"), 0.0)])
def test_bad_rolling_drift_shapes_are_one_line_input_errors(shape, tau_s, from_s):
    with pytest.raises(InputError) as info:
        drift_rolling_term(shape, tau_s, from_s)
    assert "\n" not in str(info.value)


def test_a_rolling_drift_is_written_and_read_back(tmp_path):
    """``diagnose -o`` keeps the shape: the written scenario rebuilds the same power."""
    from orange_plan.context import load_context
    from orange_plan.identify.scenario_out import write_calibrated_scenario
    from orange_plan.physics.model_builder import model_with_terms

    ctx = load_context(ROOT / "scenarios" / "kiwibot_campus.toml")
    base = model_with_terms(ctx, [*ctx.model.term_ids])
    shaped = base.with_terms([*base.terms, drift_rolling_term("step", 1800.0, 700.0)],
                             {"drift_rolling_kg": 4.0})
    path = write_calibrated_scenario(ctx.scenario, shaped, tmp_path / "out.toml")
    again = load_context(path).model
    state = _state([0.0, 699.0, 701.0], speed=1.0, crr=ctx.world.default_crr)
    assert np.asarray(again.power_W(state)) == pytest.approx(np.asarray(shaped.power_W(state)))
    assert again.terms[-1].shape == ("step", 1800.0, 700.0)


def test_a_rolling_drift_shape_without_its_term_is_refused(tmp_path):
    from orange_plan.scenario import load_scenario

    text = (ROOT / "scenarios" / "kiwibot_campus.toml").read_text()
    path = tmp_path / "s.toml"
    map_line = next(line for line in text.splitlines() if line.startswith("map = "))
    absolute = map_line.replace('"../', f'"{ROOT}/')
    path.write_text(text.replace(map_line, absolute, 1)
                    + '\n[model]\ndrift_rolling_shape = "linear"\n')
    with pytest.raises(InputError, match=r"needs 'drift_rolling' in model\.terms"):
        load_scenario(path)


def test_planning_charges_a_rising_rolling_coefficient_at_the_horizon(tmp_path):
    """Rolling rising by 10 kg over 1000 s, time limit 2000 s: planning charges
    ``rolling_kg + 20 kg`` on every step; a falling one at the start (unchanged)."""
    from planning_worlds import write_world

    from orange_plan.context import load_context
    from orange_plan.physics.model_builder import model_with_terms

    ctx = load_context(write_world(tmp_path, time_limit_s=2000.0))
    base = model_with_terms(ctx, [*ctx.model.term_ids])
    for delta, at in ((10.0, 2000.0), (-10.0, 0.0)):
        drifted = replace(ctx, model=base.with_terms(
            [*base.terms, drift_rolling_term("linear", 1000.0)], {"drift_rolling_kg": delta}))
        assert drifted.conditions.elapsed_s == at
        state = MotionState(speed_mps=1.0, crr=ctx.world.default_crr,
                            channels=drifted.conditions.channels)
        extra = float(drifted.model.traction_force_N(state) - base.traction_force_N(state))
        assert extra == pytest.approx(max(delta, 0.0) * 2.0 * G_MPS2 * ctx.world.default_crr)


# --- diagnosis on the generator's cases ------------------------------------------------------


def _diagnosed(terms, seed, kind=None):
    from orange_plan.identify.diagnose import diagnose
    from orange_plan.sim.concealed import concealed_case

    case = concealed_case(terms, seed, kind=kind)
    return case, diagnose(case.recording, case.ctx)


SHAPE_KEY = {"linear": "drift_span_s", "decay": "drift_tau_s", "step": "drift_from_s"}


@pytest.mark.timeout(900)  # a 30-minute case and its diagnosis: minutes on a loaded machine
@pytest.mark.parametrize("seed", [0, 1, 3])
def test_a_changing_rolling_coefficient_is_named_with_its_shape_and_sign(seed):
    """The rolling coefficient rising or falling by 20-50 % over the run (line, saturating
    exponential or step, the generator draws it): diagnosis names a drift, variant
    ``drift_rolling``, of the true shape and sign, and nothing else. Seed 3 is a step, which
    a payload's step fits too: the rolling step is named, not a payload."""
    case, result = _diagnosed(["drift_rolling"], seed)
    truth = case.truth["drift_rolling"]
    assert [(f.term, f.variant) for f in result.findings] == [("drift", "drift_rolling")], \
        result.to_dict()["candidates"][:6]
    found = result.findings[0]
    true_key = next(k for k in SHAPE_KEY.values() if k in truth)
    assert true_key in found.params
    value = found.params["drift_rolling_kg"]
    assert np.sign(value) == np.sign(truth["drift_rolling_kg"])
    if true_key == "drift_span_s":  # a line's size is one quantity: compare it
        assert abs(value - truth["drift_rolling_kg"]) <= Z_MAX * found.stderr["drift_rolling_kg"]
    assert result.improved.cv_rmse_W < result.baseline.cv_rmse_W
