"""Regeneration beside a missing inertia, and a drift of any shape: the physics (one form for
fitting and planning) and diagnosis on generated and real recordings."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from orange_plan.physics.model import EnergyModel
from orange_plan.physics.state import MotionState
from orange_plan.physics.terms import DRIFT_SHAPES, TERMS, drift_term

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
Z_MAX = 3.0


# --- the physics -------------------------------------------------------------------------------


def _braking_model(eff: float) -> EnergyModel:
    return EnergyModel([TERMS["inertia"], TERMS["regen"]],
                       {"inertia_kg": 100.0, "regen_efficiency": eff}, omega=0.7)


@settings(max_examples=40, deadline=None)
@given(eff=st.floats(0.0, 1.0), accel=st.floats(-3.0, 3.0), speed=st.floats(0.1, 30.0))
def test_braking_returns_eff_of_the_negative_traction_power(eff, accel, speed):
    """``P = max(0, F) v - eff max(0, -F) v`` whatever Omega: in time, on a path step, and
    the efficiency's column of the linearisation the calibration and diagnosis fit."""
    model = _braking_model(eff)
    state = MotionState(speed_mps=speed, accel_mps2=accel)
    mech_W = 100.0 * accel * speed
    expected = mech_W if mech_W >= 0 else eff * mech_W
    assert float(model.power_W(state)) == pytest.approx(expected, rel=1e-9, abs=1e-9)
    step = model.segment_energy(state, 10.0, 1.0)
    assert float(step.traversal_J) == pytest.approx(expected * 10.0 / speed, rel=1e-9, abs=1e-9)
    jac = model.power_jacobian(MotionState(speed_mps=np.array([speed]),
                                           accel_mps2=np.array([accel])))
    # d P / d eff: the negative traction power itself, as calibration and diagnosis fit it
    assert float(jac[0, 1]) == pytest.approx(min(mech_W, 0.0), rel=1e-9, abs=1e-9)


def test_planning_charges_the_fitted_efficiency_neither_0_nor_100_pct():
    """The path cost of a stop from speed: the kinetic energy back at the fitted share."""
    model = _braking_model(0.6)
    slow = MotionState(speed_mps=5.0, accel_mps2=-1.0)
    back_J = -float(model.segment_energy(slow, 12.5, 1.0).traversal_J)  # 2.5 s of braking
    assert back_J == pytest.approx(0.6 * 100.0 * 1.0 * 12.5)


@pytest.mark.parametrize("shape", DRIFT_SHAPES)
def test_drift_shapes_are_one_expression_for_numpy_and_casadi(shape):
    import casadi as ca

    term = drift_term(shape, 600.0, 900.0)
    t = np.array([0.0, 300.0, 899.0, 901.0, 1800.0])
    values = np.asarray(term.features(MotionState(speed_mps=np.ones(5),
                                                  channels={"elapsed_s": t}))[0], float)
    sym = ca.SX.sym("t")
    f = ca.Function("f", [sym], [term.features(MotionState(speed_mps=1.0 + 0 * sym,
                                                            channels={"elapsed_s": sym}))[0]])
    assert [float(f(v)) for v in t] == pytest.approx(list(values))
    expected = {"decay": np.exp(-t / 600.0), "linear": t / 600.0,
                "step": (t >= 900.0).astype(float)}[shape]
    assert values == pytest.approx(expected)


def test_the_vocabulary_drift_is_the_decay_of_the_family():
    state = MotionState(speed_mps=np.ones(3), channels={"elapsed_s": np.array([0, 600, 1e4])})
    assert np.asarray(TERMS["drift"].features(state)[0]) == pytest.approx(
        np.asarray(drift_term().features(state)[0]))


@pytest.mark.parametrize("slope", [0.05, 0.25, -0.2])
def test_the_grade_power_is_the_rate_of_climb_whatever_the_speed_measures(slope):
    """``z_m`` rises ``slope`` per metre the speed integrates to: the grade's power per unit
    mass, ``g sin_t v``, is ``g dz/dt`` exactly, for a speed along the path (wheels, a
    speedometer, the simulator) as for a horizontal one (positions). Read as a tangent
    (``s / sqrt(1 + s^2)``), the slope came out ``1/sqrt(1 + s^2)`` short (3 % at 25 %)."""
    import pandas as pd

    from orange_plan.telemetry.recording import recording_from_frame
    from orange_plan.telemetry.state import recording_state

    t = np.arange(0.0, 200.0, 0.1)
    inner = slice(100, -100)  # the smoothing's ends aside
    along = recording_from_frame(pd.DataFrame({"t_s": t, "power_W": 1.0, "v_mps": 1.0,
                                               "z_m": slope * t}))
    flat = recording_from_frame(pd.DataFrame({"t_s": t, "power_W": 1.0, "x_m": 2.0 * t,
                                              "y_m": 0.0 * t, "z_m": slope * t}))
    for rec, climb_mps in ((along, slope), (flat, slope)):
        state = recording_state(rec, grade_window_m=2.0)
        rate = np.asarray(state.sin_t) * np.asarray(state.speed_mps)
        assert rate[inner] == pytest.approx(climb_mps, abs=1e-3 * abs(climb_mps))
        assert (np.asarray(state.cos_t) ** 2 + np.asarray(state.sin_t) ** 2)[inner] == \
            pytest.approx(1.0)


# --- diagnosis on generated recordings -----------------------------------------------------


def _diagnosed(terms, seed, kind=None, duration_s=1800.0):
    from orange_plan.identify.diagnose import diagnose
    from orange_plan.sim.concealed import concealed_case

    case = concealed_case(terms, seed, kind=kind, duration_s=duration_s)
    return case, diagnose(case.recording, case.ctx)


@pytest.mark.parametrize("seed", [0, 1])
def test_regen_is_found_beside_a_missing_inertia_with_its_efficiency(seed):
    """A scenario with neither inertia nor regen: both are named, and the efficiency is the
    truth's within its uncertainty (not the 100 % an inertia column charged in full implies)."""
    case, result = _diagnosed(["inertia", "regen"], seed)
    assert "inertia" not in case.ctx.model.term_ids and "regen" not in case.ctx.model.term_ids
    found = {f.term: f for f in result.findings}
    assert {"inertia", "regen"} <= set(found), result.to_dict()["candidates"][:6]
    regen = found["regen"]
    true = case.truth["regen"]["regen_efficiency"]
    value, sd = regen.params["regen_efficiency"], regen.stderr["regen_efficiency"]
    assert abs(value - true) <= Z_MAX * sd + 0.02, (value, sd, true)
    assert value < 0.95


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_marine_drift_of_any_shape_is_found(seed):
    """A vessel's load changing by 15-35 % over the run, as a line, a saturating
    exponential or a step (the generator draws the shape)."""
    _, result = _diagnosed(["drift"], seed, kind="marine")
    assert [f.term for f in result.findings] == ["drift"], result.to_dict()["candidates"][:6]
    assert result.improved.cv_rmse_W < result.baseline.cv_rmse_W


def test_nothing_is_named_on_the_marine_null_case():
    _, result = _diagnosed([], 0, kind="marine")
    assert result.findings == [], result.to_dict()["candidates"][:6]


def test_a_found_drift_keeps_its_shape_in_the_model():
    """The improved model carries the drift of the shape diagnosis chose: its power over the
    run is the fitted contribution."""
    _, result = _diagnosed(["drift"], 2, kind="marine")
    drift = next(t for t in result.model.terms if t.id == "drift")
    d = result.design
    state = MotionState(speed_mps=np.ones(d.n), channels={"elapsed_s": d.t_s - d.t_s[0]})
    power = result.model.coefficient("drift_W") * np.asarray(drift.features(state)[0], float)
    contribution = result.improved.contribution_W("drift")
    assert np.ptp(power) == pytest.approx(np.ptp(contribution), rel=0.05)


# --- diagnosis on the real BMW i3 trips ---------------------------------------------------


@pytest.mark.skipif(not (DATA / "tum_bmw_i3").is_dir(),
                    reason="real data not present in ../shared/data")
def test_bmw_trip_regen_named_with_an_efficiency_and_a_gain_over_inertia():
    """TripA01 with the bmw_i3 scenario without inertia and regen (``bench diagnose --real``
    measures all sixteen trips)."""
    from orange_plan.bench.diagnose_real import REMOVED
    from orange_plan.bench.identify import load_runs
    from orange_plan.context import load_context
    from orange_plan.identify.diagnose import candidates, diagnose, fit_design, polish
    from orange_plan.physics.model_builder import model_with_terms

    root = Path(__file__).resolve().parents[1]
    ctx = load_context(root / "scenarios" / "bmw_i3.toml")
    ctx = replace(ctx, model=model_with_terms(
        ctx, [t for t in ctx.model.term_ids if t not in REMOVED]))
    rec = load_runs(DATA, "tum_bmw_i3", "tum_bmw_i3/TripA01.csv.gz")[0]
    result = diagnose(rec, ctx)
    found = {f.term: f for f in result.findings}
    assert "regen" in found
    assert 0.3 < found["regen"].params["regen_efficiency"] < 0.9
    pool = {c.id: c for c in candidates()}
    d = result.design
    alone = polish(d, [pool["inertia"]], fit_design(d, [pool["inertia"]]))
    both = fit_design(d, [pool["inertia"], pool["regen"]])
    assert 1.0 - both.cv_rmse_W / alone.cv_rmse_W >= 0.20
    assert not math.isnan(both.cv_rmse_W)


@pytest.mark.skipif(not (DATA / "tum_bmw_i3").is_dir(),
                    reason="real data not present in ../shared/data")
def test_a_trips_efficiency_interval_says_whether_it_pins_the_efficiency():
    """The profile likelihood of the efficiency (every other coefficient refitted inside the
    model at each value): TripA01 pins it well below 1 (0.78 fitted); TripA16, whose heater
    runs unmodelled, cannot tell its 0.97 from plausible efficiencies, and its interval says
    so by reaching both 1 and under 0.8. The car's own torque signal says the same of both:
    TripA01's motor takes back well under all of the fitted braking power, TripA16's nearly all
    (the fitted efficiency is what the car delivered, not an artefact of the fit)."""
    from orange_plan.bench.diagnose_real import bmw_regen

    root = Path(__file__).resolve().parents[1]
    (a01,) = bmw_regen(DATA, root / "scenarios" / "bmw_i3.toml", "tum_bmw_i3/TripA01.csv.gz")
    assert a01.efficiency_low <= a01.regen_efficiency <= a01.efficiency_high < 0.95
    assert a01.efficiency_low > 0.5
    assert a01.torque_efficiency == pytest.approx(a01.regen_efficiency, abs=0.05)
    from test_json_docs import compare

    compare("bench diagnose --real", {"rows": [a01.to_dict()]})  # docs/json.md's keys
    (a16,) = bmw_regen(DATA, root / "scenarios" / "bmw_i3.toml", "tum_bmw_i3/TripA16.csv.gz")
    assert a16.efficiency_high == 1.0 and a16.efficiency_low < 0.8
    assert a16.torque_efficiency > 0.9
    assert a16.torque_efficiency == pytest.approx(a16.regen_efficiency, abs=0.07)


def test_bench_real_without_trips_is_one_line_exit_2(tmp_path):
    from conftest import run_cli

    code, _, stderr = run_cli("bench", "diagnose", "--real", str(tmp_path))
    assert code == 2 and "no BMW i3 trip" in stderr and "Traceback" not in stderr


def test_a_drift_shape_is_written_and_read_back(tmp_path):
    """``diagnose -o`` keeps the shape: the written scenario rebuilds the same drift power."""
    from orange_plan.context import load_context
    from orange_plan.identify.scenario_out import write_calibrated_scenario
    from orange_plan.physics.model_builder import model_with_terms

    root = Path(__file__).resolve().parents[1]
    ctx = load_context(root / "scenarios" / "marine_survey.toml")
    base = model_with_terms(ctx, [*ctx.model.term_ids])
    shaped = base.with_terms([*base.terms, drift_term("step", 1800.0, 700.0)],
                             {"drift_W": -4.0})
    path = write_calibrated_scenario(ctx.scenario, shaped, tmp_path / "out.toml")
    again = load_context(path).model
    state = MotionState(speed_mps=np.ones(3), channels={"elapsed_s": np.array([0, 699, 701.0])})
    assert np.asarray(again.power_W(state)) == pytest.approx(np.asarray(shaped.power_W(state)))
    assert float(again.power_W(state)[2] - again.power_W(state)[1]) == pytest.approx(-4.0)


def test_a_drift_shape_without_the_drift_term_is_refused(tmp_path):
    from orange_plan.errors import InputError
    from orange_plan.scenario import load_scenario

    root = Path(__file__).resolve().parents[1]
    text = (root / "scenarios" / "marine_survey.toml").read_text()
    path = tmp_path / "s.toml"
    path.write_text(text.replace('name = "marine_survey"', 'name = "marine_survey"\nmap = "'
                                 + str(root / "maps" / "survey_bay.geojson") + '"', 1)
                    .replace('map = "../maps/survey_bay.geojson"\n', "", 1)
                    + '\n[model]\ndrift_shape = "linear"\n')
    with pytest.raises(InputError, match=r"needs 'drift' in model\.terms"):
        load_scenario(path)


def test_torque_efficiency_is_the_motors_share_of_the_models_braking_power(monkeypatch):
    """Hand-computed: speeds 10 m/s, model forces -100, -200, +50 N (braking powers -1000,
    -2000 W and one driving sample left out), torques -2, -3 Nm: the motor's power is
    torque x 10 x 9.665 / 0.35 = -552.3, -828.4 W, so 1380.7 / 3000 = 0.4602. Without a
    torque column there is nothing to compare: NaN."""
    from types import SimpleNamespace

    import pandas as pd

    from orange_plan.bench import diagnose_real
    from orange_plan.identify.diagnosis import fitting

    state = SimpleNamespace(speed_mps=np.full(3, 10.0))
    base = SimpleNamespace(traction_force_N=lambda s: np.array([-100.0, -200.0, 50.0]))
    inside = SimpleNamespace(state=state, base=base)
    monkeypatch.setattr(fitting, "absorb",
                        lambda d, chosen, fit: SimpleNamespace(design=inside))
    d = SimpleNamespace(columns_of=frozenset({"motor_torque_Nm"}),
                        frame=pd.DataFrame({"motor_torque_Nm": [-2.0, -3.0, 5.0]}))
    share = diagnose_real.torque_efficiency(d, [], None)
    assert share == pytest.approx(5 * 10 * 9.665 / 0.35 / 3000, rel=1e-12)
    assert share == pytest.approx(0.4602, abs=1e-4)
    nothing = SimpleNamespace(columns_of=frozenset(), frame=None)
    assert math.isnan(diagnose_real.torque_efficiency(nothing, [], None))
