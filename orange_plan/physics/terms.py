"""Physics terms of the ORangE model, one per vocabulary id.

Battery power is a sum of terms, each linear in its own coefficient(s) ``theta``:

    P_battery = sum_power theta*phi + max(0, sum_force theta*phi) * v + sum_rate theta*phi

* ``power`` terms are battery-side powers drawn for the whole mission time (the paper's
  ancillary energy, Eq. 4-5 and Eq. 10, plus a drone's hover power).
* ``force`` terms are traction forces divided by the manoeuvring efficiency Omega (the
  paper's Eq. 1-2 and Eq. 7: rolling, aerodynamic drag, grade, inertia). They are summed
  and clipped at zero *before* being charged, because a robot without regeneration gets
  nothing back when the net force is negative. The ``regen`` term is the
  explicit exception: it returns a fraction of the negative part.
* ``rate`` terms are charged per radian of heading change (skid-steer turning losses).
* ``battery`` terms are losses inside the battery that grow with the square of the current
  (I^2 R, Joule heating of the cells): with the load power ``P`` (the three groups above) the
  battery delivers ``P (1 + B P)``, ``B = sum_battery theta*phi`` [1/W] (``R / V^2`` for a
  resistance R at terminal voltage V). Not linear in theta: the calibration, the reserve and
  diagnosis linearise it (``EnergyModel.power_jacobian``).

The coefficients are lumped battery-side quantities: ``rolling_kg = m/Omega``,
``drag_kg_per_m = c/Omega``, ``grade_kg = inertia_kg = m/Omega``. Every feature is written
with operators that numpy arrays and CasADi symbols share (see ``ops``), so the planner and
the speed optimiser evaluate the same expressions.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from orange_plan.errors import InputError
from orange_plan.physics import ops
from orange_plan.physics.state import Channel, MotionState

G_MPS2 = 9.81
"""Standard gravity used by the reference model [m/s^2]."""
DEFAULT_REGEN_EFFICIENCY = 0.5
"""A priori ``regen_efficiency``: fraction of braking/descending energy recovered [-]."""

Group = Literal["power", "force", "rate", "regen", "battery"]


@dataclass(frozen=True)
class Term:
    """One physics term: a vocabulary id, its group, coefficient names and feature maths.

    Parameters
    ----------
    id : vocabulary id
    group : ``power`` [W per coefficient unit], ``force`` [N per coefficient unit],
        ``rate`` [J/rad per coefficient unit], ``regen`` (recovery fraction) or ``battery``
        [1/W per coefficient unit] (module docstring)
    coefficients : names of the coefficients (unit suffixed)
    feature : ``feature(state) -> tuple`` of one feature per coefficient
    description : one line for the documentation and reports
    channels : the ``MotionState.channels`` the feature reads (beyond the motion fields)
    shape : a ``drift``'s ``(shape, tau_s, from_s)`` (``drift_term``), an ``hvac_ambient``'s
        set-points ``(heat_below_C, cool_above_C)`` (``hvac_ambient_term``); () for every
        other term
    """

    id: str
    group: Group
    coefficients: tuple[str, ...]
    feature: Callable[[MotionState], tuple]
    description: str
    channels: tuple[Channel, ...] = ()
    shape: tuple = ()

    def features(self, state: MotionState) -> tuple:
        """Feature values ``phi`` (one per coefficient) at ``state``."""
        return self.feature(state)


# --- features: one small pure function per physics term --------------------------------


def _per_sample(value, state: MotionState):
    """``value`` broadcast to one entry per sample (the shape of the speed), numpy or CasADi."""
    return value + 0.0 * state.speed_mps


def rolling_per_kg(state: MotionState):
    """``g crr cos(theta)`` [N/kg]: the rolling force per kg every rolling term scales."""
    return G_MPS2 * state.crr * state.cos_t


def one_feature(state: MotionState):
    """Constant 1: a power drawn whatever the motion [W/W]."""
    return (_per_sample(1.0, state),)


def sensor_rate_feature(state: MotionState):
    """Sensor operating frequency f_s [Hz] (the paper's Eq. 5: P_sense = s0 + s1 f_s)."""
    return (_per_sample(state.sensor_rate_Hz, state),)


def rolling_feature(state: MotionState):
    """Rolling resistance per unit m/Omega: ``g crr cos(theta)`` [N/kg] (Eq. 1)."""
    return (rolling_per_kg(state),)


def aero_drag_feature(state: MotionState):
    """Drag per unit c/Omega: ``|a| (a . u)`` with ``a = v u - w`` [m^2/s^2] (Eq. 1).

    With no wind this is ``v^2``; a head wind raises it, a tail wind lowers it (and can make
    it negative: the wind pushes).
    """
    ax, ay = state.air_velocity()
    return (ops.sqrt(ax * ax + ay * ay) * (ax * state.dir_x + ay * state.dir_y),)


def grade_feature(state: MotionState):
    """Weight component along the slope per unit m/Omega: ``g sin(theta)`` [N/kg] (Eq. 1)."""
    return (_per_sample(G_MPS2 * state.sin_t, state),)


def inertia_feature(state: MotionState):
    """Force to accelerate per unit m/Omega: ``dv/dt`` [N/kg]."""
    return (_per_sample(state.accel_mps2, state),)


def turning_feature(state: MotionState):
    """Heading rate magnitude ``|yaw rate|`` [rad/s]; in path form, |heading change| [rad]."""
    return (ops.fabs(state.yaw_rate_radps),)


def regen_feature(state: MotionState):
    """Regen has no feature of its own: it scales the negative net traction (EnergyModel)."""
    return (_per_sample(0.0, state),)


def surface_rolling_term(surface_names: tuple[str, ...]) -> Term:
    """Rolling resistance with one coefficient per surface (calibrated per surface).

    Coefficient ``rolling_kg_<name>`` plays the role of m/Omega on that surface only; the
    plain ``rolling`` term then covers points whose ``surface_code`` is -1 (default ground).
    """

    def feature(state: MotionState):
        base = rolling_per_kg(state)
        return tuple(base * (state.surface_code == code) for code in range(len(surface_names)))

    return Term(
        id="surface_rolling",
        group="force",
        coefficients=tuple(f"rolling_kg_{name}" for name in surface_names),
        feature=feature,
        description="rolling resistance with a coefficient per surface",
    )


COULOMB_SPEED_MPS = 0.01
"""Regularisation speed of Coulomb friction: ``sign(v) ~ min(1, |v| / v_c)`` [m/s]. Far below
any planned speed; it only shapes the start and the stop."""
COULOMB_YAW_RATE_RADPS = 0.05
"""Regularisation heading rate of the skid-steer scrub (Coulomb) friction [rad/s]."""


def _wheels_moving(state: MotionState):
    """Fraction of Coulomb friction engaged while the wheels turn, 0 at rest, 1 moving [-].

    ``min(1, |v| / v_c + |yaw rate| / w_c)``: a skid-steer spinning in place (v = 0) turns
    its wheels too.
    """
    return ops.fmin(ops.fabs(state.speed_mps) / COULOMB_SPEED_MPS
                    + ops.fabs(state.yaw_rate_radps) / COULOMB_YAW_RATE_RADPS, 1.0)


def rolling_torque_feature(state: MotionState):
    """Rolling force per kg while the wheels turn, whatever their speed: ``g crr cos(theta)
    min(1, |v|/v_c + |yaw rate|/w_c)`` [N/kg].

    For a log whose "power" is bus voltage x *motor* current (BorealTC: 24 V x |I|): motor
    current is proportional to torque, so that power is the wheel force times the motor's
    free (no-load, full-voltage) wheel speed, not times the actual speed. Coefficient
    ``rolling_torque_kg_mps`` = m v_free / Omega [kg m/s].
    """
    return (rolling_per_kg(state) * _wheels_moving(state),)


def turning_torque_feature(state: MotionState):
    """Skid-steer scrub engaged: ``min(1, |yaw rate| / w_c)`` [-].

    Turning a skid-steer slides its wheels sideways against Coulomb friction: the resisting
    moment (Wong: mu m g l / 4) hardly depends on the turn rate, so the motor *current* (and a
    bus voltage x motor current "power") is a constant while turning. Coefficient
    ``turning_torque_W`` = (2 M_r / B) v_free / Omega [W] (B track width).
    """
    return (ops.fmin(ops.fabs(state.yaw_rate_radps) / COULOMB_YAW_RATE_RADPS, 1.0),)


DRIFT_TAU_S = 1200.0
"""Time constant of the warm-up drift [s]: a cold drivetrain (gear oil, bearings), cold tyres
and the cabin pull-down settle over tens of minutes. Not fitted (it would make the term
non-linear): chosen by leave-one-run-out cross-validation on fitting trips only
(docs/benchmarks/calibration.md)."""


HVAC_W = Channel("hvac_W", 0.0, np.inf, "cabin heating / air-conditioning electrical power, "
                 "measured or planned [W]")
HEATER_REQUEST_W = Channel("heater_request_W", 0.0, np.inf, "requested cabin heating power "
                           "(a climate-control demand, not a meter) [W]")
ELAPSED_S = Channel("elapsed_s", 0.0, np.inf, "time since the start of the trip or mission "
                    "(drivetrain warm-up) [s]")


def hvac_feature(state: MotionState):
    """Cabin heating / air-conditioning electrical power ``P_hvac`` [W/-] (measured or planned).

    Coefficient ``hvac_fraction`` [-]: the share of that power drawn from the traction battery
    (1 when the compressor or heater sits on the high-voltage bus, as in an electric car).
    """
    return (_per_sample(state.channel(HVAC_W.name), state),)


def heater_feature(state: MotionState):
    """Requested cabin heating power ``P_req`` [W/-] (a demand signal, not the heater's draw).

    Coefficient ``heater_fraction`` [-]: the mean share of the request the high-voltage heater
    actually draws. The heater cycles and stops once the coolant is warm, so the share is well
    below 1 and only calibration can tell it (BMW i3 trips: 0.28 +- 0.04; docs/benchmarks/calibration.md).
    """
    return (_per_sample(state.channel(HEATER_REQUEST_W.name), state),)


def drift_feature(state: MotionState):
    """Warm-up fraction ``exp(-t / tau)`` at time t since the start [-] (tau = DRIFT_TAU_S).

    Coefficient ``drift_W`` [W]: the extra battery power at a cold start, decaying as the
    drivetrain, tyres and cabin reach their working temperature (viscous losses fall).
    """
    return (_per_sample(ops.exp(-state.channel(ELAPSED_S.name) / DRIFT_TAU_S), state),)


DRIFT_SHAPES = ("decay", "linear", "step")
"""Shapes of a slow change of a power over mission time t (``drift_shape_feature``):
``decay`` ``exp(-t / tau)`` (a cold start settling; with a negative ``drift_W`` a rise that
levels off), ``linear`` ``t / tau`` (a steady rise or fall, ``drift_W`` per ``tau``), ``step``
``[t >= t0]`` (a load switched on or off at ``t0``)."""


STEP_RISE_S = 1.0
"""How long a drift's ``step`` takes to rise from 0 to 1, centred on its time [s]: a ramp, so
that CasADi can differentiate it (``step_ramp``)."""


def step_ramp(t, from_s: float):
    """A drift's ``step`` at ``from_s`` [s] at the times ``t`` [s]: 0 until half of STEP_RISE_S
    before it, 1 from half of it after, linear between (numpy or CasADi) [-]."""
    return ops.fmin(ops.fmax((t - from_s + 0.5 * STEP_RISE_S) / STEP_RISE_S, 0.0), 1.0)


def drift_shape_feature(shape: str, tau_s: float = DRIFT_TAU_S, from_s: float = 0.0):
    """The feature of a drift of ``shape`` (``DRIFT_SHAPES``): a function of the state [-].

    Parameters
    ----------
    shape : ``"decay"``, ``"linear"`` or ``"step"``
    tau_s : time constant of ``decay``, time scale of ``linear`` (the change per ``tau_s``) [s]
    from_s : time of a ``step`` [s] (``step_ramp``: it rises over STEP_RISE_S)
    """
    if shape not in DRIFT_SHAPES:
        raise InputError(f"drift shape {shape!r} is not one of {', '.join(DRIFT_SHAPES)}")
    if not (np.isfinite(tau_s) and tau_s > 0 and np.isfinite(from_s) and from_s >= 0):
        raise InputError(f"a drift needs tau_s > 0 and from_s >= 0 (finite), got tau_s = "
                         f"{tau_s!r} s, from_s = {from_s!r} s")

    def feature(state: MotionState):
        t = state.channel(ELAPSED_S.name)
        if shape == "decay":
            value = ops.exp(-t / tau_s)
        elif shape == "linear":
            value = t / tau_s
        else:
            value = step_ramp(t, from_s)
        return (_per_sample(value, state),)

    return feature


def drift_term(shape: str = "decay", tau_s: float = DRIFT_TAU_S, from_s: float = 0.0) -> Term:
    """The ``drift`` term of one shape (``drift_shape_feature``); coefficient ``drift_W`` [W]
    (either sign: a power that rises or falls). ``drift_term()`` is the vocabulary's cold-start
    decay."""
    return Term("drift", "power", ("drift_W",), drift_shape_feature(shape, tau_s, from_s),
                f"a power changing over mission time ({shape}, tau {tau_s:g} s, from {from_s:g} s)",
                (ELAPSED_S,), (shape, float(tau_s), float(from_s)))


def drift_rolling_term(shape: str = "decay", tau_s: float = DRIFT_TAU_S,
                       from_s: float = 0.0) -> Term:
    """The ``drift_rolling`` term: the rolling coefficient changing over mission time, of a
    drift's ``shape`` (``drift_shape_feature``) [N/kg].

    Feature ``s(t) g crr cos(theta)``, ``s`` the shape: the rolling force per kg of the
    change. Coefficient ``drift_rolling_kg`` [kg], either sign: the change of ``rolling_kg``
    per unit of the shape (a line's change over ``tau_s``, a decay's at the start, a step's
    size), as tyres warm and soften or a track's surface wears, wets or dries. A force, so it
    is charged through the traction clip like the rolling term it changes."""
    shape_of = drift_shape_feature(shape, tau_s, from_s)

    def feature(state: MotionState):
        return (shape_of(state)[0] * rolling_per_kg(state),)

    return Term("drift_rolling", "force", ("drift_rolling_kg",), feature,
                f"the rolling coefficient changing over mission time ({shape}, tau {tau_s:g} s, "
                f"from {from_s:g} s)", (ELAPSED_S,), (shape, float(tau_s), float(from_s)))


HVAC_SETPOINT_C = 20.0
"""Cabin / enclosure temperature an HVAC holds [degC]: heating below it, cooling above."""
BATTERY_REFERENCE_C = 25.0
"""Cell temperature at which the battery's internal resistance is its nominal value [degC];
below it the resistance grows (electrolyte conductivity falls with temperature)."""

AMBIENT_C = Channel("ambient_C", -90.0, 150.0, "ambient (outside air or water) temperature; in "
                    "planning the scenario's [environment] ambient_C [degC]")
BATTERY_C = Channel("battery_C", -90.0, 150.0, "battery cell temperature; in planning the "
                    "scenario's ambient_C [degC]")


HVAC_SETPOINT_RANGE_C = (5.0, 35.0)
"""Set-points a climate control may hold [degC]: the range diagnosis scans, and the range a
scenario's ``hvac_ambient_heat_below_C`` / ``hvac_ambient_cool_above_C`` must lie in."""


def hvac_ambient_feature(heat_below_C: float = HVAC_SETPOINT_C,
                         cool_above_C: float = HVAC_SETPOINT_C):
    """The heating and cooling features of a climate control that heats below
    ``heat_below_C`` and cools above ``cool_above_C`` (a dead band between them, none when
    they are equal): ``(max(0, T_heat - T), max(0, T - T_cool))`` [K], T the ambient
    temperature.

    With no HVAC meter, the heating and cooling draw follow the temperature difference the
    climate control works against (heat flow through the enclosure ~ UA (T_set - T)); inside
    the dead band neither runs. Coefficients ``hvac_heat_W_per_K``, ``hvac_cool_W_per_K``
    [W/K] (battery side).
    """
    lo, hi = HVAC_SETPOINT_RANGE_C
    if not (lo <= heat_below_C <= cool_above_C <= hi):
        raise InputError(f"an HVAC needs {lo:g} <= heat_below_C <= cool_above_C <= {hi:g} "
                         f"degC, got {heat_below_C!r} and {cool_above_C!r}")

    def feature(state: MotionState):
        temp = state.channel(AMBIENT_C.name)
        return (_per_sample(ops.fmax(heat_below_C - temp, 0.0), state),
                _per_sample(ops.fmax(temp - cool_above_C, 0.0), state))

    return feature


def hvac_ambient_term(heat_below_C: float = HVAC_SETPOINT_C,
                      cool_above_C: float = HVAC_SETPOINT_C) -> Term:
    """The ``hvac_ambient`` term of a climate control with these set-points
    (``hvac_ambient_feature``); ``hvac_ambient_term()`` is the vocabulary's, holding
    HVAC_SETPOINT_C with no dead band. Its ``shape`` is ``(heat_below_C, cool_above_C)``."""
    return Term("hvac_ambient", "power", ("hvac_heat_W_per_K", "hvac_cool_W_per_K"),
                hvac_ambient_feature(heat_below_C, cool_above_C),
                f"heating below {heat_below_C:g} C / cooling above {cool_above_C:g} C, "
                "following the ambient temperature (no HVAC meter)",
                (AMBIENT_C,), (float(heat_below_C), float(cool_above_C)))


def battery_resistance_feature(state: MotionState):
    """Constant 1 [-]: the I^2 R loss ``B P^2`` with ``B = battery_loss_per_W`` [1/W] = R/V^2."""
    return (_per_sample(1.0, state),)


def battery_temperature_feature(state: MotionState):
    """Degrees below the reference cell temperature ``max(0, T_ref - T_battery)`` [K].

    Coefficient ``battery_cold_loss_per_W_K`` [1/(W K)]: the extra I^2 R loss factor per
    kelvin below BATTERY_REFERENCE_C (internal resistance rises as the cells cool).
    """
    return (_per_sample(ops.fmax(BATTERY_REFERENCE_C - state.channel(BATTERY_C.name), 0.0),
                        state),)


TERMS: dict[str, Term] = {
    t.id: t
    for t in (
        Term("ancillary", "power", ("ancillary_W",), one_feature,
             "sensing base + computing + communication power, battery side (Eq. 10)"),
        Term("sensor_rate", "power", ("sensor_W_per_Hz",), sensor_rate_feature,
             "sensing power per Hz of sensor rate, battery side (Eq. 5)"),
        Term("hover", "power", ("hover_W",), one_feature,
             "aerial power to stay aloft, battery side"),
        Term("rolling", "force", ("rolling_kg",), rolling_feature,
             "rolling resistance crr m g cos(theta) / Omega (Eq. 1)"),
        Term("aero_drag", "force", ("drag_kg_per_m",), aero_drag_feature,
             "aerodynamic (or hydrodynamic) drag c |a|(a.u) / Omega with wind (Eq. 1, 7)"),
        Term("grade", "force", ("grade_kg",), grade_feature,
             "weight along the slope m g sin(theta) / Omega (Eq. 1)"),
        Term("inertia", "force", ("inertia_kg",), inertia_feature,
             "acceleration force m dv/dt / Omega"),
        Term("turning", "rate", ("turn_J_per_rad",), turning_feature,
             "skid-steer turning losses per radian of heading change, battery side"),
        Term("regen", "regen", ("regen_efficiency",), regen_feature,
             "fraction of braking/descending mechanical energy recovered"),
        Term("rolling_torque", "power", ("rolling_torque_kg_mps",), rolling_torque_feature,
             "rolling force x motor free speed while the wheels turn (motor-current power)"),
        Term("turning_torque", "power", ("turning_torque_W",), turning_torque_feature,
             "skid-steer scrub at constant torque while turning (motor-current power)"),
        Term("hvac", "power", ("hvac_fraction",), hvac_feature,
             "share of the cabin heating / air-conditioning power drawn from the battery",
             (HVAC_W,)),
        Term("heater", "power", ("heater_fraction",), heater_feature,
             "share of the requested cabin heating power drawn by the high-voltage heater",
             (HEATER_REQUEST_W,)),
        Term("drift", "power", ("drift_W",), drift_feature,
             "extra power at a cold start, decaying with time constant DRIFT_TAU_S",
             (ELAPSED_S,), ("decay", DRIFT_TAU_S, 0.0)),
        drift_rolling_term(),
        hvac_ambient_term(),
        Term("battery_resistance", "battery", ("battery_loss_per_W",),
             battery_resistance_feature,
             "I^2 R loss inside the battery: delivered power P (1 + B P), B = R / V^2"),
        Term("battery_temperature", "battery", ("battery_cold_loss_per_W_K",),
             battery_temperature_feature,
             "extra I^2 R loss per kelvin of cell temperature below 25 C", (BATTERY_C,)),
    )
}
"""The vocabulary terms with fixed coefficients; ``surface_rolling`` is built per map."""

VARIANT_OF = {"rolling_torque": "rolling", "turning_torque": "turning", "heater": "hvac",
              "hvac_ambient": "hvac", "surface_label": "surface_rolling",
              "drift_rolling": "drift"}
"""Terms of our own that are variants of a vocabulary id (reports give both)."""


def spec_id(term_id: str) -> str:
    """The vocabulary id a term reports under (its own id unless a variant)."""
    return VARIANT_OF.get(term_id, term_id)


REFERENCE_TERM_IDS = ("ancillary", "sensor_rate", "hover", "rolling", "aero_drag", "grade",
                      "turning")
"""The reference model: switched on by the scenario's physical values
(``model_builder.reference_term_ids``)."""
EXTRA_TERM_IDS = (*(t for t in TERMS if t not in REFERENCE_TERM_IDS), "surface_rolling")
"""Terms a scenario adds through ``[model] terms``: every other vocabulary term."""


def model_coefficient_names(extra_terms) -> set[str]:
    """Coefficient names a scenario's [model] table may set: the reference terms' and those
    of ``extra_terms`` (per-surface ones go by their ``rolling_kg_`` prefix)."""
    return {c for t in (*REFERENCE_TERM_IDS, *extra_terms) if t in TERMS
            for c in TERMS[t].coefficients}


def default_ground_rolling_feature(state: MotionState):
    """Rolling per unit m/Omega on default ground only (``surface_code < 0``) [N/kg].

    EnergyModel uses it for ``rolling`` whenever ``surface_rolling`` is present, so a point on
    a surface polygon is charged by its surface coefficient alone, not twice.
    """
    return (rolling_per_kg(state) * (state.surface_code < 0),)


ROLLING_DEFAULT_GROUND = Term(
    "rolling", "force", ("rolling_kg",), default_ground_rolling_feature,
    "rolling resistance on default ground (surfaces are charged by surface_rolling)",
)
"""The ``rolling`` term as it stands next to ``surface_rolling``."""
