"""Every physics term: a hand-computed value, a shape/broadcast test and a bad-input test.

Values are battery side with lumped coefficients (``rolling_kg = m/Omega`` etc.), g = 9.81.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from orange_plan.errors import InputError
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.state import MotionState
from orange_plan.physics.terms import G_MPS2, TERMS, surface_rolling_term

OMEGA = 0.72  # (1 - 0.2) * (1 - 0.1)


def single(term_id: str, omega: float = OMEGA, **theta) -> EnergyModel:
    """A model holding one term (``regen`` comes with ``grade`` so it has a force to act on)."""
    if term_id == "surface_rolling":
        terms = [surface_rolling_term(("grass", "tile"))]
    elif term_id == "regen":
        terms = [TERMS["grade"], TERMS["regen"]]
    elif term_id == "battery_resistance":  # an in-battery loss needs a load to act on
        terms = [TERMS["rolling"], TERMS[term_id]]
    elif term_id == "battery_temperature":
        terms = [TERMS["ancillary"], TERMS[term_id]]
    else:
        terms = [TERMS[term_id]]
    return EnergyModel(terms, theta, omega=omega)


# Coefficients used for every term below (battery-side, lumped).
THETA = {
    "ancillary": {"ancillary_W": 8.75},
    "sensor_rate": {"sensor_W_per_Hz": 0.125},
    "hover": {"hover_W": 150.0},
    "rolling": {"rolling_kg": 12.5},
    "surface_rolling": {"rolling_kg_grass": 20.0, "rolling_kg_tile": 5.0},
    "aero_drag": {"drag_kg_per_m": 0.5},
    "grade": {"grade_kg": 12.5},
    "inertia": {"inertia_kg": 12.5},
    "turning": {"turn_J_per_rad": 3.0},
    "regen": {"grade_kg": 12.5, "regen_efficiency": 0.5},
    "rolling_torque": {"rolling_torque_kg_mps": 140.0},
    "turning_torque": {"turning_torque_W": 140.0},
    "hvac": {"hvac_fraction": 0.9},
    "heater": {"heater_fraction": 0.3},
    "drift": {"drift_W": 1200.0},
    "drift_rolling": {"drift_rolling_kg": 6.0},
    "hvac_ambient": {"hvac_heat_W_per_K": 30.0, "hvac_cool_W_per_K": 50.0},
    "battery_resistance": {"rolling_kg": 12.5, "battery_loss_per_W": 0.001},
    "battery_temperature": {"ancillary_W": 100.0, "battery_cold_loss_per_W_K": 1e-4},
}


def model_for(term_id: str) -> EnergyModel:
    return single(term_id, **THETA[term_id])


def test_every_vocabulary_term_is_covered_here():
    assert set(THETA) == set(TERMS) | {"surface_rolling"}


# --- hand-computed values ---------------------------------------------------------------


def test_ancillary_hand_value():
    m = model_for("ancillary")
    # drawn whatever the motion: 8.75 W, also standing still
    assert float(m.power_W(MotionState(speed_mps=0.0))) == pytest.approx(8.75)
    # segment: L = 10 m at 0.5 m/s with D = 0.8 -> mission time 10 / 0.5 / 0.8 = 25 s
    e = m.segment_energy(MotionState(speed_mps=0.5), 10.0, 0.8)
    assert float(e.mission_time_s) == pytest.approx(25.0)
    assert float(e.moving_time_s) == pytest.approx(20.0)
    assert float(e.ancillary_J) == pytest.approx(8.75 * 25.0)  # 218.75 J
    assert float(e.traversal_J) == 0.0


def test_sensor_rate_hand_value():
    m = model_for("sensor_rate")
    # 0.125 W/Hz * 10 Hz = 1.25 W
    assert float(m.power_W(MotionState(speed_mps=1.0, sensor_rate_Hz=10.0))) == pytest.approx(1.25)
    # over 4 m at 1 m/s, D = 0.5: 1.25 W * 8 s = 10 J
    e = m.segment_energy(MotionState(speed_mps=1.0, sensor_rate_Hz=10.0), 4.0, 0.5)
    assert float(e.total_J) == pytest.approx(10.0)


def test_hover_hand_value():
    m = model_for("hover")
    # 150 W while flying 20 m at 4 m/s with D = 1: 5 s -> 750 J
    e = m.segment_energy(MotionState(speed_mps=4.0), 20.0, 1.0)
    assert float(e.ancillary_J) == pytest.approx(750.0)
    assert float(m.power_W(MotionState(speed_mps=0.0))) == pytest.approx(150.0)


def test_rolling_hand_value():
    m = model_for("rolling")
    s = MotionState(speed_mps=2.0, crr=0.05, cos_t=0.8)
    # F = 12.5 kg * 9.81 * 0.05 * 0.8 = 4.905 N; P = F v = 9.81 W
    assert float(m.traction_force_N(s)) == pytest.approx(4.905)
    assert float(m.power_W(s)) == pytest.approx(9.81)
    # over L = 10 m: 49.05 J
    assert float(m.segment_energy(s, 10.0, 1.0).traversal_J) == pytest.approx(49.05)


def test_surface_rolling_hand_value():
    m = model_for("surface_rolling")
    s = MotionState(speed_mps=1.0, crr=np.array([0.1, 0.02, 0.3]),
                    surface_code=np.array([0, 1, -1]))
    # grass: 20 * 9.81 * 0.1 = 19.62 N; tile: 5 * 9.81 * 0.02 = 0.981 N; default ground
    # (code -1) belongs to the plain rolling term, so 0 here
    np.testing.assert_allclose(m.traction_force_N(s), [19.62, 0.981, 0.0])
    assert m.names == ("rolling_kg_grass", "rolling_kg_tile")


@pytest.mark.parametrize(
    ("dir_xy", "wind_xy", "speed", "expected_N"),
    [
        # no wind: c v^2 = 0.5 * 3^2 = 4.5 N
        ((1.0, 0.0), (0.0, 0.0), 3.0, 4.5),
        # head wind: north at 3 m/s, wind from the north blowing south at 2 m/s
        # a = (0, 3) - (0, -2) = (0, 5): 0.5 * 5 * 5 = 12.5 N
        ((0.0, 1.0), (0.0, -2.0), 3.0, 12.5),
        # tail wind: south at 3 m/s, same wind: a = (0, -3) - (0, -2) = (0, -1):
        # |a| (a.u) = 1 * 1 -> 0.5 N
        ((0.0, -1.0), (0.0, -2.0), 3.0, 0.5),
        # cross wind: east at 3 m/s, wind blowing south at 4 m/s: a = (3, 4), |a| = 5,
        # a.u = 3 -> 0.5 * 15 = 7.5 N
        ((1.0, 0.0), (0.0, -4.0), 3.0, 7.5),
        # tail wind faster than the robot: south at 1 m/s, wind south at 3 m/s:
        # a = (0, -1) - (0, -3) = (0, 2), a.u = -2 -> 0.5 * 2 * (-2) = -2 N (the wind pushes)
        ((0.0, -1.0), (0.0, -3.0), 1.0, -2.0),
    ],
)
def test_aero_drag_hand_value_with_wind(dir_xy, wind_xy, speed, expected_N):
    m = model_for("aero_drag")
    s = MotionState(speed_mps=speed, dir_x=dir_xy[0], dir_y=dir_xy[1],
                    wind_x_mps=wind_xy[0], wind_y_mps=wind_xy[1])
    assert float(m.traction_force_N(s)) == pytest.approx(expected_N)
    # no recovery without regen: power = max(0, F) v
    assert float(m.power_W(s)) == pytest.approx(max(0.0, expected_N) * speed)


def test_grade_hand_value():
    m = model_for("grade")
    up = MotionState(speed_mps=2.0, sin_t=0.1, cos_t=math.sqrt(1 - 0.01))
    # F = 12.5 * 9.81 * 0.1 = 12.2625 N; P = 24.525 W
    assert float(m.traction_force_N(up)) == pytest.approx(12.2625)
    assert float(m.power_W(up)) == pytest.approx(24.525)
    # downhill without regen: nothing comes back
    assert float(m.power_W(up.with_(sin_t=-0.1))) == 0.0


def test_inertia_hand_value():
    m = model_for("inertia")
    # F = 12.5 kg * 0.4 m/s^2 = 5 N; P = 5 * 2 = 10 W; braking costs nothing
    assert float(m.power_W(MotionState(speed_mps=2.0, accel_mps2=0.4))) == pytest.approx(10.0)
    assert float(m.power_W(MotionState(speed_mps=2.0, accel_mps2=-0.4))) == 0.0


def test_turning_hand_value():
    m = model_for("turning")
    # time domain: 3 J/rad * 0.5 rad/s = 1.5 W (either turning direction)
    assert float(m.power_W(MotionState(speed_mps=1.0, yaw_rate_radps=-0.5))) == pytest.approx(1.5)
    # path domain: a quarter turn costs 3 * pi/2 = 4.712 J
    assert float(m.turning_energy_J(math.pi / 2)) == pytest.approx(3 * math.pi / 2)
    e = m.segment_energy(MotionState(speed_mps=1.0), 5.0, 1.0, heading_change_rad=math.pi / 2)
    assert float(e.turning_J) == pytest.approx(4.712389)


def test_regen_hand_value():
    m = model_for("regen")
    down = MotionState(speed_mps=1.0, sin_t=-0.1, cos_t=math.sqrt(0.99))
    # lumped force F = 12.5 * 9.81 * (-0.1) = -12.2625 N (= m g sin / Omega with m = 9 kg)
    # recovered: eff of the negative traction power, eff |F| v = 0.5 * 12.2625 * 1 W
    # (Omega is in the lumped force already, not applied again)
    assert float(m.power_W(down)) == pytest.approx(-0.5 * 12.2625)
    # uphill regen changes nothing: 12.2625 W
    assert float(m.power_W(down.with_(sin_t=0.1))) == pytest.approx(12.2625)


# --- shape and broadcasting -------------------------------------------------------------

# The state field each term depends on, with a sample value per element.
OWN_FIELD = {
    "ancillary": ("speed_mps", [0.5, 1.0, 2.0]),
    "sensor_rate": ("sensor_rate_Hz", [1.0, 5.0, 20.0]),
    "hover": ("speed_mps", [1.0, 3.0, 5.0]),
    "rolling": ("crr", [0.01, 0.05, 0.2]),
    "surface_rolling": ("surface_code", [0, 1, -1]),
    "aero_drag": ("wind_x_mps", [-2.0, 0.0, 1.5]),
    "grade": ("sin_t", [-0.05, 0.0, 0.1]),
    "inertia": ("accel_mps2", [-0.3, 0.2, 0.5]),
    "turning": ("yaw_rate_radps", [-1.0, 0.0, 0.4]),
    "regen": ("sin_t", [-0.2, -0.05, 0.1]),
    "rolling_torque": ("crr", [0.01, 0.05, 0.2]),
    "turning_torque": ("yaw_rate_radps", [-0.02, 0.0, 0.04]),
    "hvac": ("hvac_W", [0.0, 400.0, 1500.0]),
    "heater": ("heater_request_W", [0.0, 3000.0, 7000.0]),
    "drift": ("elapsed_s", [0.0, 600.0, 3600.0]),
    "drift_rolling": ("elapsed_s", [0.0, 600.0, 3600.0]),
    "hvac_ambient": ("ambient_C", [0.0, 20.0, 35.0]),
    "battery_resistance": ("crr", [0.01, 0.05, 0.2]),
    "battery_temperature": ("battery_C", [-10.0, 10.0, 30.0]),
}
BASE = {"crr": 0.05, "dir_x": 1.0}


@pytest.mark.parametrize("term_id", sorted(OWN_FIELD))
def test_term_scalar_in_scalar_out(term_id):
    m = model_for(term_id)
    field, values = OWN_FIELD[term_id]
    s = MotionState.from_values({"speed_mps": 1.2, **BASE, field: values[-1]})
    p = m.power_W(s)
    assert np.ndim(p) == 0 and np.isfinite(float(p))
    e = m.segment_energy(s, 3.0, 0.9, heading_change_rad=0.3)
    assert np.ndim(e.total_J) == 0
    assert all(np.ndim(phi) == 0 for t in m.terms for phi in t.features(s))


@pytest.mark.parametrize("term_id", sorted(OWN_FIELD))
def test_term_vector_matches_scalars(term_id):
    m = model_for(term_id)
    field, values = OWN_FIELD[term_id]
    kw = {"speed_mps": 1.2, **BASE}
    p = m.power_W(MotionState.from_values({**kw, field: np.array(values)}))
    p = np.broadcast_to(p, (3,))
    expected = [float(m.power_W(MotionState.from_values({**kw, field: v}))) for v in values]
    np.testing.assert_allclose(p, expected)
    assert np.ptp(expected) > 0 or term_id in ("ancillary", "hover")  # the field matters


@pytest.mark.parametrize("term_id", sorted(OWN_FIELD))
def test_term_broadcasts_n1_by_m(term_id):
    m = model_for(term_id)
    field, values = OWN_FIELD[term_id]
    speeds = np.array([0.4, 0.9, 1.5, 2.5])  # (m,) = (4,)
    col = np.array(values)[:, None]  # (n, 1) = (3, 1)
    lengths = np.array([1.0, 2.0, 3.0, 4.0])
    turn = 0.25
    if field == "speed_mps":  # broadcast the term's own field against the step lengths
        s = MotionState.from_values({**BASE, "speed_mps": col})
    elif term_id == "turning":  # path domain: the heading change is turning's input
        s = MotionState.from_values({**BASE, "speed_mps": speeds})
        turn = np.abs(col)
    else:
        s = MotionState.from_values({**BASE, "speed_mps": speeds, field: col})
    e = m.segment_energy(s, lengths, 0.8, heading_change_rad=turn)
    total = np.asarray(e.total_J)
    assert total.shape == (3, 4)
    for i, v in enumerate(values):
        for j in range(4):
            sp = col[i, 0] if field == "speed_mps" else speeds[j]
            one = MotionState.from_values({**BASE, "speed_mps": sp, field: v})
            t = abs(v) if term_id == "turning" else 0.25
            ref = m.segment_energy(one, lengths[j], 0.8, heading_change_rad=t).total_J
            assert total[i, j] == pytest.approx(float(ref), rel=1e-12, abs=1e-12)
    assert np.ptp(total) > 0


# --- bad input --------------------------------------------------------------------------


def test_ancillary_bad_missing_coefficient():
    with pytest.raises(InputError, match=r"no value for coefficient\(s\) \['ancillary_W'\]"):
        EnergyModel([TERMS["ancillary"]], {})


def test_sensor_rate_bad_negative_rate():
    with pytest.raises(InputError, match=r"sensor_rate_Hz = -1 is outside"):
        MotionState(speed_mps=1.0, sensor_rate_Hz=-1.0).validate()


def test_hover_bad_non_finite_coefficient():
    with pytest.raises(InputError, match="coefficients must be finite"):
        EnergyModel([TERMS["hover"]], {"hover_W": float("nan")})


def test_rolling_bad_crr():
    with pytest.raises(InputError, match=r"MotionState.crr = 1.5 is outside \[0, 1\]"):
        MotionState(speed_mps=1.0, crr=np.array([0.1, 1.5])).validate()


def test_surface_rolling_bad_missing_surface_coefficient():
    with pytest.raises(InputError, match="rolling_kg_tile"):
        EnergyModel([surface_rolling_term(("grass", "tile"))], {"rolling_kg_grass": 1.0})


def test_aero_drag_bad_negative_speed():
    with pytest.raises(InputError, match=r"speed_mps = -1 is outside"):
        MotionState(speed_mps=-1.0, wind_x_mps=2.0).validate()


def test_grade_bad_sine():
    with pytest.raises(InputError, match=r"sin_t = 1.5 is outside \[-1, 1\]"):
        MotionState(speed_mps=1.0, sin_t=1.5).validate()


def test_inertia_bad_non_finite_accel():
    with pytest.raises(InputError, match="accel_mps2 holds a non-finite value"):
        MotionState(speed_mps=1.0, accel_mps2=np.inf).validate()


def test_turning_bad_coefficient_of_no_term():
    with pytest.raises(InputError, match=r"\['turn_W_per_rad'\] belong to no term"):
        EnergyModel([TERMS["turning"]], {"turn_J_per_rad": 1.0, "turn_W_per_rad": 1.0})


def test_regen_bad_omega():
    with pytest.raises(InputError, match=r"omega = 1.5 must be in \(0, 1\]"):
        single("regen", omega=1.5, **THETA["regen"])


def test_validate_accepts_good_state_and_symbols():
    import casadi as ca

    s = MotionState(speed_mps=ca.MX.sym("v"), crr=0.1, sin_t=-0.2, cos_t=0.98)
    assert s.validate() is s
    assert G_MPS2 == 9.81


# --- motor-current (torque) terms: rolling_torque, turning_torque -------------------------


def test_rolling_torque_hand_value():
    m = model_for("rolling_torque")
    # moving: 140 kg m/s * 9.81 * 0.05 N/kg = 68.67 W, whatever the speed
    assert float(m.power_W(MotionState(speed_mps=0.5, crr=0.05))) == pytest.approx(68.67)
    assert float(m.power_W(MotionState(speed_mps=1.0, crr=0.05))) == pytest.approx(68.67)
    # near a stop the Coulomb friction fades: 0.005 / 0.01 = half -> 34.335 W; at rest 0
    assert float(m.power_W(MotionState(speed_mps=0.005, crr=0.05))) == pytest.approx(34.335)
    assert float(m.power_W(MotionState(speed_mps=0.0, crr=0.05))) == 0.0
    # spinning in place turns the wheels too: full 68.67 W
    spin = MotionState(speed_mps=0.0, crr=0.05, yaw_rate_radps=-0.5)
    assert float(m.power_W(spin)) == pytest.approx(68.67)
    # path domain (a power term): 10 m at 0.5 m/s, D = 0.8 -> 25 s -> 1716.75 J
    e = m.segment_energy(MotionState(speed_mps=0.5, crr=0.05), 10.0, 0.8)
    assert float(e.total_J) == pytest.approx(1716.75)


def test_turning_torque_hand_value():
    m = model_for("turning_torque")
    # scrub at constant torque: 140 W while turning, at any turn rate above 0.05 rad/s
    assert float(m.power_W(MotionState(speed_mps=0.3, yaw_rate_radps=-0.3))) == pytest.approx(140.0)
    assert float(m.power_W(MotionState(speed_mps=0.0, yaw_rate_radps=1.0))) == pytest.approx(140.0)
    # 0.02 rad/s: 0.02 / 0.05 = 0.4 of it -> 56 W; straight: nothing
    assert float(m.power_W(MotionState(speed_mps=0.3, yaw_rate_radps=0.02))) == pytest.approx(56.0)
    assert float(m.power_W(MotionState(speed_mps=0.3))) == 0.0


def test_rolling_torque_bad_non_finite_coefficient():
    with pytest.raises(InputError, match="coefficients must be finite"):
        EnergyModel([TERMS["rolling_torque"]], {"rolling_torque_kg_mps": float("inf")})


def test_turning_torque_bad_non_finite_yaw_rate():
    with pytest.raises(InputError, match="yaw_rate_radps holds a non-finite value"):
        MotionState(speed_mps=1.0, yaw_rate_radps=np.nan).validate()


def test_torque_terms_numpy_and_casadi_agree_near_a_stop():
    import casadi as ca

    m = EnergyModel([TERMS["rolling_torque"], TERMS["turning_torque"]],
                    {**THETA["rolling_torque"], **THETA["turning_torque"]})
    speed = np.array([0.0, 0.004, 0.02, 0.5])  # below and above the Coulomb speed
    kw = {"crr": 0.05, "yaw_rate_radps": np.array([0.0, 0.01, -0.03, 0.4])}
    v = ca.MX.sym("v", 4)
    f = ca.Function("p", [v], [m.power_W(MotionState(speed_mps=v, **kw))])
    np.testing.assert_allclose(np.asarray(f(speed)).ravel(),
                               m.power_W(MotionState(speed_mps=speed, **kw)), rtol=1e-12)


# --- cabin HVAC and warm-up drift (BMW i3 trips) --------------------------------------------


def test_hvac_hand_value():
    m = model_for("hvac")
    # 0.9 x 1500 W of air conditioning = 1350 W, driving or standing
    assert float(m.power_W(MotionState(speed_mps=12.0).with_(hvac_W=1500.0))) == pytest.approx(1350.0)
    assert float(m.power_W(MotionState(speed_mps=0.0).with_(hvac_W=1500.0))) == pytest.approx(1350.0)
    assert float(m.power_W(MotionState(speed_mps=12.0))) == 0.0  # planning default: no HVAC
    # path domain (a power term): 100 m at 10 m/s, D = 0.8 -> 12.5 s x 1350 W = 16875 J
    e = m.segment_energy(MotionState(speed_mps=10.0).with_(hvac_W=1500.0), 100.0, 0.8)
    assert float(e.total_J) == pytest.approx(16875.0)


def test_heater_hand_value():
    m = model_for("heater")
    # 0.3 x 7000 W requested = 2100 W, driving or standing; no request (planning) -> 0 W
    assert float(m.power_W(MotionState(speed_mps=15.0).with_(heater_request_W=7000.0))) == pytest.approx(
        2100.0)
    assert float(m.power_W(MotionState(speed_mps=0.0).with_(heater_request_W=7000.0))) == pytest.approx(
        2100.0)
    assert float(m.power_W(MotionState(speed_mps=15.0))) == 0.0
    # path domain (a power term): 300 m at 15 m/s, D = 1 -> 20 s x 2100 W = 42000 J
    e = m.segment_energy(MotionState(speed_mps=15.0).with_(heater_request_W=7000.0), 300.0, 1.0)
    assert float(e.total_J) == pytest.approx(42000.0)


def test_heater_bad_negative_request():
    with pytest.raises(InputError, match=r"MotionState.heater_request_W = -1 is outside"):
        MotionState(speed_mps=1.0).with_(heater_request_W=np.array([0.0, -1.0])).validate()


def test_drift_hand_value():
    from orange_plan.physics.terms import DRIFT_TAU_S

    m = model_for("drift")
    assert DRIFT_TAU_S == 1200.0
    # 1200 W at a cold start, 1200 e^-1 = 441.455 W after tau, 1200 e^-2 = 162.402 W after 2 tau
    for elapsed, watts in ((0.0, 1200.0), (1200.0, 441.455), (2400.0, 162.402)):
        s = MotionState(speed_mps=8.0).with_(elapsed_s=elapsed)
        assert float(m.power_W(s)) == pytest.approx(watts, abs=1e-3)
    # standing still draws it too (cabin pull-down, pumps)
    assert float(m.power_W(MotionState(speed_mps=0.0).with_(elapsed_s=1200.0))) == pytest.approx(441.455,
                                                                                         abs=1e-3)


def test_drift_rolling_hand_value():
    """The vocabulary's rolling drift decays like the power drift: 6 kg of extra rolling at a
    cold start, at 2 m/s on crr 0.05: 6 * 9.81 * 0.05 * 2 = 5.886 W, e^-1 of it after tau."""
    m = model_for("drift_rolling")
    for elapsed, watts in ((0.0, 5.886), (1200.0, 5.886 * math.exp(-1.0))):
        s = MotionState(speed_mps=2.0, crr=0.05).with_(elapsed_s=elapsed)
        assert float(m.power_W(s)) == pytest.approx(watts, rel=1e-9)
    # a force: nothing at rest, unlike the power drift
    assert float(m.power_W(MotionState(speed_mps=0.0, crr=0.05))) == 0.0


def test_drift_rolling_bad_shape():
    from orange_plan.physics.terms import drift_rolling_term

    with pytest.raises(InputError, match="drift shape 'sine' is not one of decay, linear, step"):
        drift_rolling_term("sine")


def test_hvac_bad_negative_power():
    with pytest.raises(InputError, match=r"MotionState.hvac_W = -5 is outside \[0, inf\]"):
        MotionState(speed_mps=1.0).with_(hvac_W=np.array([100.0, -5.0])).validate()


def test_drift_bad_elapsed_time():
    with pytest.raises(InputError, match=r"MotionState.elapsed_s = -1 is outside"):
        MotionState(speed_mps=1.0).with_(elapsed_s=-1.0).validate()
    with pytest.raises(InputError, match="elapsed_s holds a non-finite value"):
        MotionState(speed_mps=1.0).with_(elapsed_s=np.nan).validate()


# --- diagnosed physics: HVAC on the ambient temperature, in-battery I^2 R losses ------------


def test_hvac_ambient_hand_value():
    m = model_for("hvac_ambient")
    # 5 C: 15 K below the 20 C setpoint x 30 W/K = 450 W; 30 C: 10 K above x 50 W/K = 500 W
    for temp, watts in ((5.0, 450.0), (20.0, 0.0), (30.0, 500.0)):
        s = MotionState(speed_mps=2.0).with_(ambient_C=temp)
        assert float(m.power_W(s)) == pytest.approx(watts)
    # path domain (a power term): 50 m at 5 m/s, D = 0.5 -> 20 s x 450 W = 9000 J
    e = m.segment_energy(MotionState(speed_mps=5.0).with_(ambient_C=5.0), 50.0, 0.5)
    assert float(e.total_J) == pytest.approx(9000.0)


def test_battery_resistance_hand_value():
    m = model_for("battery_resistance")
    # load: rolling 12.5 kg x 9.81 x 0.05 = 6.13125 N at 1 m/s = 6.13125 W;
    # delivered 6.13125 (1 + 0.001 x 6.13125) = 6.168842 W
    s = MotionState(speed_mps=1.0, crr=0.05)
    assert float(m.power_W(s)) == pytest.approx(6.13125 * (1 + 0.001 * 6.13125))
    assert float(m.power_W(s)) == pytest.approx(6.168842, abs=1e-6)
    # path: 10 m at 1 m/s, D = 0.8: traction 61.3125 J over 12.5 s mission time -> mean load
    # 4.905 W -> 61.3125 x (1 + 0.004905) = 61.61324 J
    e = m.segment_energy(s, 10.0, 0.8)
    assert float(e.total_J) == pytest.approx(61.61324, abs=1e-5)


def test_battery_temperature_hand_value():
    m = model_for("battery_temperature")
    # 100 W load; 5 C cells: 20 K x 1e-4 = 0.002 /W -> 100 (1 + 0.2) = 120 W; 30 C: 100 W
    for temp, watts in ((5.0, 120.0), (25.0, 100.0), (30.0, 100.0)):
        assert float(m.power_W(MotionState(speed_mps=0.0).with_(battery_C=temp))) == pytest.approx(watts)


def test_battery_loss_jacobian_matches_finite_differences():
    """Calibration and the reserve linearise the I^2 R loss: its Jacobian must be the
    derivative of the power and of the path energy."""
    m = EnergyModel([TERMS["ancillary"], TERMS["rolling"], TERMS["turning"],
                     TERMS["battery_resistance"], TERMS["battery_temperature"]],
                    {"ancillary_W": 20.0, "rolling_kg": 12.5, "turn_J_per_rad": 3.0,
                     "battery_loss_per_W": 2e-3, "battery_cold_loss_per_W_K": 1e-4}, omega=OMEGA)
    s = MotionState(speed_mps=np.array([0.5, 1.0, 2.0]), crr=0.05,
                    yaw_rate_radps=np.array([0.0, 0.3, -0.2])).with_(battery_C=np.array([0.0, 10.0, 30.0]))
    lengths, turns = np.array([1.0, 2.0, 5.0]), np.array([0.0, 0.4, 1.0])
    for value, jac in ((lambda th: m.power_W(s, th), m.power_jacobian(s)),
                       (lambda th: m.segment_energy(s, lengths, 0.8, turns, th).total_J,
                        m.segment_energy_jacobian(s, lengths, 0.8, turns))):
        for k in range(len(m.names)):
            h = 1e-6 * max(1.0, abs(m.theta[k]))
            up, down = m.theta.copy(), m.theta.copy()
            up[k] += h
            down[k] -= h
            numeric = (np.asarray(value(up)) - np.asarray(value(down))) / (2 * h)
            np.testing.assert_allclose(jac[:, k], numeric, rtol=1e-5, atol=1e-9)


def test_battery_temperature_bad_cell_temperature():
    with pytest.raises(InputError, match=r"MotionState.battery_C = 400 is outside \[-90, 150\]"):
        MotionState(speed_mps=1.0).with_(battery_C=np.array([20.0, 400.0])).validate()


def test_hvac_ambient_bad_non_finite_temperature():
    with pytest.raises(InputError, match="ambient_C holds a non-finite value"):
        MotionState(speed_mps=1.0).with_(ambient_C=np.inf).validate()


def test_battery_resistance_bad_non_finite_coefficient():
    with pytest.raises(InputError, match="coefficients must be finite"):
        single("battery_resistance", rolling_kg=1.0, battery_loss_per_W=np.nan)
