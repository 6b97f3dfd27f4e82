"""EnergyModel: numpy/CasADi agreement, jacobians, covariance bookkeeping, bad input."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from orange_plan.errors import InputError
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.state import MotionState
from orange_plan.physics.terms import TERMS, surface_rolling_term

OMEGA = 0.72
FULL_THETA = {
    "ancillary_W": 8.0, "sensor_W_per_Hz": 0.1, "hover_W": 3.0, "rolling_kg": 14.0,
    "rolling_kg_grass": 18.0, "rolling_kg_tile": 11.0, "drag_kg_per_m": 0.4, "grade_kg": 13.9,
    "inertia_kg": 13.9, "turn_J_per_rad": 2.5, "regen_efficiency": 0.6,
    "rolling_torque_kg_mps": 140.0, "turning_torque_W": 140.0,
    "hvac_fraction": 0.9, "heater_fraction": 0.3, "drift_W": 5.0,
}


def full_model() -> EnergyModel:
    """Every term, inertia, regen and surface_rolling included."""
    terms = [TERMS["ancillary"], TERMS["sensor_rate"], TERMS["hover"], TERMS["rolling"],
             surface_rolling_term(("grass", "tile")), TERMS["aero_drag"], TERMS["grade"],
             TERMS["inertia"], TERMS["turning"], TERMS["regen"],
             TERMS["rolling_torque"], TERMS["turning_torque"], TERMS["hvac"], TERMS["heater"],
             TERMS["drift"]]
    return EnergyModel(terms, FULL_THETA, omega=OMEGA)


def random_state(rng, n: int, speed) -> dict:
    """Random numeric fields (everything but speed) for n steps."""
    sin_t = rng.uniform(-0.3, 0.3, n)
    heading = rng.uniform(0, 2 * np.pi, n)
    return dict(
        speed_mps=speed, cos_t=np.sqrt(1 - sin_t**2), sin_t=sin_t,
        dir_x=np.cos(heading), dir_y=np.sin(heading),
        wind_x_mps=rng.uniform(-4, 4, n), wind_y_mps=rng.uniform(-4, 4, n),
        crr=rng.uniform(0.0, 0.2, n), accel_mps2=rng.uniform(-1, 1, n),
        yaw_rate_radps=rng.uniform(-1, 1, n), sensor_rate_Hz=rng.uniform(0, 30, n),
        surface_code=rng.integers(-1, 2, n),
        hvac_W=rng.uniform(0, 20, n), heater_request_W=rng.uniform(0, 50, n),
        elapsed_s=rng.uniform(0, 3000, n),
    )


@pytest.mark.parametrize("sym", [ca.MX, ca.SX])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_numpy_and_casadi_agree(sym, seed):
    rng = np.random.default_rng(seed)
    n = 40
    model = full_model()
    speed = rng.uniform(0.2, 6.0, n)
    fields = random_state(rng, n, speed)
    length = rng.uniform(0.1, 5.0, n)
    turn = rng.uniform(0, np.pi, n)
    duty = 0.7

    num_state = MotionState.from_values(fields)
    e_num = np.asarray(model.segment_energy(num_state, length, duty, turn).total_J)
    p_num = np.asarray(model.power_W(num_state))
    force = model.traction_force_N(num_state)
    assert (force > 0).any() and (force < 0).any()  # both sides of max(0, F) and regen used

    v = sym.sym("v", n)
    sym_state = MotionState.from_values({**fields, "speed_mps": v})
    e_sym = model.segment_energy(sym_state, length, duty, turn).total_J
    p_sym = model.power_W(sym_state)
    assert isinstance(e_sym, sym) and isinstance(p_sym, sym)
    f = ca.Function("f", [v], [e_sym, p_sym])
    e_ca, p_ca = (np.asarray(x).ravel() for x in f(speed))
    np.testing.assert_allclose(e_ca, e_num, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(p_ca, p_num, rtol=1e-9, atol=1e-9)


def test_casadi_symbolic_theta_matches_numeric():
    rng = np.random.default_rng(7)
    model = full_model()
    state = MotionState.from_values(random_state(rng, 15, rng.uniform(0.2, 3, 15)))
    th = ca.MX.sym("theta", len(model.names))
    f = ca.Function("p", [th], [model.power_W(state, theta=th)])
    np.testing.assert_allclose(np.asarray(f(model.theta)).ravel(), model.power_W(state),
                               rtol=1e-9)


def test_segment_energy_hand_value_reference_model():
    # 10 kg robot, Omega 0.72: rolling_kg = grade_kg = 10/0.72; c = 0.36 -> drag 0.5
    m = EnergyModel([TERMS["ancillary"], TERMS["rolling"], TERMS["aero_drag"], TERMS["grade"]],
                    {"ancillary_W": 8.75, "rolling_kg": 10 / 0.72, "drag_kg_per_m": 0.5,
                     "grade_kg": 10 / 0.72}, omega=0.72)
    # L = 5 m with dz = 3 m, d = 4 m: cos = 0.8, sin = 0.6; v = 2 m/s, crr = 0.05, D = 0.5
    s = MotionState(speed_mps=2.0, cos_t=0.8, sin_t=0.6, crr=0.05)
    e = m.segment_energy(s, 5.0, 0.5)
    # F = 0.05*10*9.81*0.8 + 0.36*4 + 10*9.81*0.6 = 3.924 + 1.44 + 58.86 = 64.224 N
    # traversal = 64.224 * 5 / 0.72 = 446.0 J; mission time 5/(2*0.5) = 5 s -> 43.75 J
    assert float(e.traversal_J) == pytest.approx(446.0)
    assert float(e.ancillary_J) == pytest.approx(43.75)
    assert float(e.total_J) == pytest.approx(489.75)
    assert float(e.moving_time_s) == pytest.approx(2.5)


def test_surface_points_are_not_charged_twice():
    m = EnergyModel([TERMS["rolling"], surface_rolling_term(("grass",))],
                    {"rolling_kg": 10.0, "rolling_kg_grass": 20.0})
    s = MotionState(speed_mps=1.0, crr=0.1, surface_code=np.array([0, -1]))
    # grass: 20 * 9.81 * 0.1 = 19.62 N only; default ground: 10 * 9.81 * 0.1 = 9.81 N
    np.testing.assert_allclose(m.traction_force_N(s), [19.62, 9.81])


def test_jacobians_match_finite_differences():
    rng = np.random.default_rng(3)
    model = full_model()
    n = 30
    state = MotionState.from_values(random_state(rng, n, rng.uniform(0.3, 4.0, n)))
    length = rng.uniform(0.5, 3.0, n)
    turn = rng.uniform(0, 2, n)
    jac = model.segment_energy_jacobian(state, length, 0.8, turn)
    pj = model.power_jacobian(state)
    assert jac.shape == (n, len(model.names)) and pj.shape == (n, len(model.names))
    h = 1e-6
    for k, name in enumerate(model.names):
        bumped = model.with_theta({name: model.theta[k] + h})
        de = (bumped.segment_energy(state, length, 0.8, turn).total_J
              - model.segment_energy(state, length, 0.8, turn).total_J) / h
        dp = (bumped.power_W(state) - model.power_W(state)) / h
        np.testing.assert_allclose(jac[:, k], de, rtol=1e-4, atol=1e-5, err_msg=name)
        np.testing.assert_allclose(pj[:, k], dp, rtol=1e-4, atol=1e-5, err_msg=name)


def test_jacobian_times_theta_is_energy_without_regen():
    rng = np.random.default_rng(4)
    terms = [t for t in full_model().terms if t.id != "regen"]
    theta = {k: v for k, v in FULL_THETA.items() if k != "regen_efficiency"}
    model = EnergyModel(terms, theta, omega=OMEGA)
    state = MotionState.from_values(random_state(rng, 25, rng.uniform(0.3, 4.0, 25)))
    e = model.segment_energy(state, 2.0, 0.9, 0.5).total_J
    np.testing.assert_allclose(model.segment_energy_jacobian(state, 2.0, 0.9, 0.5) @ model.theta, e)
    np.testing.assert_allclose(model.power_jacobian(state) @ model.theta, model.power_W(state))


def test_covariance_bookkeeping():
    cov = np.diag([4.0, 9.0])
    m = EnergyModel([TERMS["ancillary"], TERMS["rolling"]],
                    {"ancillary_W": 5.0, "rolling_kg": 10.0}, cov)
    assert m.stderr() == {"ancillary_W": 2.0, "rolling_kg": 3.0}
    # g' Cov g with g = (1, 2): 1*4*1 + 2*9*2 = 40 J^2
    assert float(m.energy_variance_J2(np.array([1.0, 2.0]))) == pytest.approx(40.0)
    m2 = m.with_theta({"rolling_kg": 12.0})
    assert m2.coefficient("rolling_kg") == 12.0 and m.coefficient("rolling_kg") == 10.0
    np.testing.assert_array_equal(m2.cov, cov)
    m3 = m.with_terms([TERMS["rolling"], TERMS["grade"]], {"grade_kg": 10.0})
    assert m3.names == ("rolling_kg", "grade_kg")
    assert m3.cov[0, 0] == 9.0 and m3.cov[1, 1] == 0.0
    assert m3.as_dict() == {"rolling_kg": 10.0, "grade_kg": 10.0}


def test_predictive_variance_adds_the_run_to_run_discrepancy():
    cov = np.diag([4.0, 9.0])
    m = EnergyModel([TERMS["ancillary"], TERMS["rolling"]],
                    {"ancillary_W": 5.0, "rolling_kg": 10.0}, cov, discrepancy_rel_sd=0.1)
    # g' Cov g = 40 J^2 (above) plus (0.1 x 100 J)^2 = 100 J^2
    assert float(m.predictive_variance_J2(np.array([1.0, 2.0]), 100.0)) == pytest.approx(140.0)
    # kept through with_theta / with_terms, replaced by with_discrepancy
    assert m.with_theta({"rolling_kg": 1.0}).discrepancy_rel_sd == 0.1
    assert m.with_terms([TERMS["rolling"]], {}).discrepancy_rel_sd == 0.1
    assert m.with_discrepancy(0.0).predictive_variance_J2(np.array([1.0, 2.0]), 100.0) == 40.0


@settings(max_examples=50, deadline=None)
@given(rel=st.floats(0.0, 2.0), energy=st.floats(-1e6, 1e6),
       g=st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=2),
       sd=st.lists(st.floats(0.0, 1e2), min_size=2, max_size=2))
def test_predictive_variance_is_parameter_variance_plus_discrepancy(rel, energy, g, sd):
    m = EnergyModel([TERMS["ancillary"], TERMS["rolling"]],
                    {"ancillary_W": 5.0, "rolling_kg": 10.0}, np.diag(np.square(sd)),
                    discrepancy_rel_sd=rel)
    param = float(m.energy_variance_J2(np.array(g)))
    total = float(m.predictive_variance_J2(np.array(g), energy))
    assert total >= param >= 0.0
    assert total - param == pytest.approx((rel * energy) ** 2, rel=1e-9, abs=1e-6 * (1 + param))


def test_bad_model_inputs():
    with pytest.raises(InputError, match="repeat an id"):
        EnergyModel([TERMS["rolling"], TERMS["rolling"]], {"rolling_kg": 1.0})
    with pytest.raises(InputError, match=r"cov has shape \(1, 1\), expected \(2, 2\)"):
        EnergyModel([TERMS["ancillary"], TERMS["rolling"]],
                    {"ancillary_W": 1.0, "rolling_kg": 1.0}, np.eye(1))
    with pytest.raises(InputError, match=r"omega = 0 must be in \(0, 1\]"):
        EnergyModel([TERMS["rolling"]], {"rolling_kg": 1.0}, omega=0)
    with pytest.raises(InputError, match=r"discrepancy_rel_sd = -0\.1 must be >= 0"):
        EnergyModel([TERMS["rolling"]], {"rolling_kg": 1.0}, discrepancy_rel_sd=-0.1)
    with pytest.raises(InputError, match="no coefficient named 'crr_kg'"):
        EnergyModel([TERMS["rolling"]], {"rolling_kg": 1.0}).coefficient("crr_kg")
