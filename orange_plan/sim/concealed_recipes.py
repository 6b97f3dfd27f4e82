"""The concealed-effect cases' term recipes: how each concealed term edits the truth and the
seen scenarios, the route it asks for and the power it adds after the simulation
(``sim.concealed`` makes the case from them)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from orange_plan.physics.model import EnergyModel
from orange_plan.physics.state import MotionState
from orange_plan.physics.terms import HVAC_SETPOINT_C, TERMS, drift_term, hvac_ambient_feature
from orange_plan.sim.truth import Wind

BATTERY_WARM_C = 25.0
"""Battery temperature above which the cold loss vanishes [C]."""
SENSOR_RATES_HZ = (5.0, 10.0, 20.0, 30.0)
"""Rates the ``sensor_rate`` recording switches among [Hz]."""


@dataclass
class _Plan:
    """What the term recipes decide before and after the simulation (mutable, internal)."""

    kind: str
    duration_s: float
    truth_toml: dict
    seen_toml: dict
    sim_truth: dict = field(default_factory=dict)      # Truth(...) keyword arguments
    route_style: str = "mixed"
    landed: bool = False
    battery_cold: bool = False
    sensor_schedule: bool = False
    power_effects: list[Callable] = field(default_factory=list)    # (plan, frame, P, rng) -> P
    battery_effects: list[Callable] = field(default_factory=list)  # same, applied last
    truth: dict[str, dict[str, float]] = field(default_factory=dict)
    measurement: dict[str, float] = field(default_factory=dict)
    mass_over_omega_kg: float = 0.0
    surface_names: tuple[str, ...] = ()
    labels: bool = False   # a classifier's ``surface`` column, the seen map without surfaces
    ambient_C: tuple[float, float] = (0.0, 35.0)   # range of the ambient temperature's walk
    concealed: tuple[str, ...] = ()

    def shape_route(self, style: str) -> None:
        """Ask for a route style; the first term that asks wins (recipes run in
        ``_ROUTE_PRIORITY`` order)."""
        if self.route_style in ("mixed", "aerial"):
            self.route_style = style
        elif style == "hills" and self.route_style.startswith("surface:"):
            self.route_style += "+hills"  # a surface route that climbs between its visits


# --- term recipes: each edits the truth / seen scenarios and the plan ----------------------


def _model(toml: dict) -> dict:
    return toml.setdefault("model", {})


def _add_model_term(toml: dict, term: str) -> None:
    terms = _model(toml).setdefault("terms", [])
    if term not in terms:
        terms.append(term)


def _ancillary(plan: _Plan, rng) -> None:
    # s1 goes too: at the constant sensor rate of these runs s1 f_s is itself a constant draw,
    # so a scenario keeping it would not have left the constant draw out
    for toml in (plan.truth_toml, plan.seen_toml):
        toml["ancillary"].update(s0_W=0.0, compute_W=0.0, comm_W=0.0, s1_W_per_Hz=0.0)
    share = rng.uniform(0.10, 0.35)
    plan.power_effects.append(lambda p, frame, power, _rng: power + _power_term_W(
        "ancillary", {"ancillary_W": p.truth["ancillary"]["ancillary_W"]}, frame))
    plan.power_effects.insert(0, _sizer("ancillary", "ancillary_W", share,
                                        lambda frame: np.ones(len(frame))))


def _sensor_rate(plan: _Plan, rng) -> None:
    for toml in (plan.truth_toml, plan.seen_toml):
        toml["ancillary"]["s1_W_per_Hz"] = 0.0
    plan.sensor_schedule = True
    share = rng.uniform(0.08, 0.25)
    plan.power_effects.insert(0, _sizer("sensor_rate", "sensor_W_per_Hz", share,
                                        lambda frame: frame["sensor_rate_Hz"].to_numpy(float)))
    plan.power_effects.append(lambda p, frame, power, _rng: power + _power_term_W(
        "sensor_rate", p.truth["sensor_rate"], frame))


def _hover(plan: _Plan, rng) -> None:
    nominal = plan.truth_toml["robot"]["hover_W"]
    for toml in (plan.truth_toml, plan.seen_toml):
        toml["robot"]["hover_W"] = 0.0
    plan.truth["hover"] = {"hover_W": float(nominal * rng.uniform(0.85, 1.15))}
    plan.landed = True

    def add(p, frame, power, _rng):
        airborne = frame["_airborne"].to_numpy(bool)
        return power + airborne * _power_term_W("hover", p.truth["hover"], frame)

    plan.power_effects.append(add)


def _rolling(plan: _Plan, rng) -> None:
    true = plan.mass_over_omega_kg * rng.uniform(0.8, 1.25)
    _model(plan.truth_toml)["rolling_kg"] = true
    _model(plan.seen_toml)["rolling_kg"] = 0.0
    plan.truth["rolling"] = {"rolling_kg": float(true)}
    plan.shape_route("walks")  # a sidewalk robot's walks: on the lawn rolling is over half


def _surface_rolling(plan: _Plan, rng) -> None:
    names = sorted(plan.surface_names)
    surface = names[int(rng.integers(len(names)))]
    _add_model_term(plan.truth_toml, "surface_rolling")
    name = f"rolling_kg_{surface}"
    true = plan.mass_over_omega_kg * rng.uniform(1.8, 3.0)
    _model(plan.truth_toml)[name] = true
    plan.truth["surface_rolling"] = {name: float(true)}
    plan.shape_route(f"surface:{surface}")


def _aero_drag(plan: _Plan, rng) -> None:
    robot = plan.truth_toml["robot"]
    robot["drag_coeff_kg_per_m"] = robot["drag_coeff_kg_per_m"] * rng.uniform(0.7, 1.5)
    plan.seen_toml["robot"]["drag_coeff_kg_per_m"] = 0.0
    omega = (1 - plan.truth_toml["losses"]["motor"]) * (1 - plan.truth_toml["losses"]["mechanical"])
    plan.truth["aero_drag"] = {"drag_kg_per_m": float(robot["drag_coeff_kg_per_m"] / omega)}
    plan.shape_route("fast")


def _grade(plan: _Plan, rng) -> None:
    true = plan.mass_over_omega_kg * rng.uniform(0.8, 1.25)
    _model(plan.truth_toml)["grade_kg"] = true
    _model(plan.seen_toml)["grade_kg"] = 0.0
    plan.truth["grade"] = {"grade_kg": float(true)}
    plan.shape_route("hills")


def _inertia(plan: _Plan, rng) -> None:
    _add_model_term(plan.truth_toml, "inertia")
    true = plan.mass_over_omega_kg * rng.uniform(0.8, 1.25)
    _model(plan.truth_toml)["inertia_kg"] = true
    plan.truth["inertia"] = {"inertia_kg": float(true)}
    plan.sim_truth["stop_every_s"] = float(rng.uniform(10.0, 25.0))


def _regen(plan: _Plan, rng) -> None:
    # regen needs braking: the truth has inertia, and the seen model too unless inertia is
    # concealed beside it (a scenario with neither, as a car's a-priori road-load model)
    for toml in (plan.truth_toml,) if "inertia" in plan.concealed else (plan.truth_toml,
                                                                          plan.seen_toml):
        _add_model_term(toml, "inertia")
    _add_model_term(plan.truth_toml, "regen")
    true = rng.uniform(0.4, 0.8)
    _model(plan.truth_toml)["regen_efficiency"] = true
    plan.truth["regen"] = {"regen_efficiency": float(true)}
    plan.sim_truth.setdefault("stop_every_s", float(rng.uniform(15.0, 30.0)))
    plan.shape_route("hills")


def _turning(plan: _Plan, rng) -> None:
    true = rng.uniform(15.0, 45.0)
    plan.truth_toml["robot"]["turn_coeff_W_s_per_rad"] = true
    plan.seen_toml["robot"]["turn_coeff_W_s_per_rad"] = 0.0
    plan.truth["turning"] = {"turn_J_per_rad": float(true)}
    plan.shape_route("turns")


def _wind(plan: _Plan, rng) -> None:
    speed, from_deg = rng.uniform(2.0, 6.0), rng.uniform(0.0, 360.0)
    for toml, (s, d) in ((plan.truth_toml, (speed, from_deg)), (plan.seen_toml, (0.0, 0.0))):
        toml["environment"].update(wind_speed_mps=s, wind_from_deg=d)
    plan.sim_truth["wind"] = Wind(speed, from_deg, gust_std_mps=speed * rng.uniform(0.1, 0.2),
                                  gust_tau_s=rng.uniform(5.0, 15.0), recorded=False)
    plan.truth["wind"] = {"wind_speed_mps": float(speed), "wind_from_deg": float(from_deg)}


def _payload(plan: _Plan, rng) -> None:
    mass = plan.truth_toml["robot"]["mass_kg"]
    extra = mass * rng.uniform(0.1, 0.4) * (1 if rng.random() < 0.5 else -1)
    plan.sim_truth.update(payload_kg=float(extra),
                          payload_from_s=float(plan.duration_s * rng.uniform(0.2, 0.8)))
    # payload_from_s is moved onto the recording's clock once the run is trimmed
    plan.truth["payload"] = {"payload_kg": float(extra)}


def _hvac(plan: _Plan, rng) -> None:
    mode = ("heat", "cool", "both")[int(rng.integers(3))]
    share = rng.uniform(0.08, 0.30)
    plan.power_effects.append(_hvac_adder("hvac", mode, share))


def _hvac_adder(key: str, mode: str, share: float, least_K: float = 0.0,
                heat_below_C: float = HVAC_SETPOINT_C,
                cool_above_C: float = HVAC_SETPOINT_C) -> Callable:
    """The power effect of heating below ``heat_below_C`` and / or cooling above
    ``cool_above_C`` (``mode``) drawing ``share`` of the mean power together; truth under
    ``key`` (with the set-points where they are not the vocabulary's one). Only a side the
    ambient reaches by more than ``least_K`` on average works (a trip that never drops below
    the set-point does not heat; at least the side it reaches most)."""

    def add(p, frame, power, _rng):
        t_c = frame["ambient_C"].to_numpy(float)
        state = MotionState(speed_mps=np.ones(t_c.size), channels={"ambient_C": t_c})
        heating, cooling = hvac_ambient_feature(heat_below_C, cool_above_C)(state)
        feats = {"hvac_heat_W_per_K": np.asarray(heating, float),
                 "hvac_cool_W_per_K": np.asarray(cooling, float)}
        chosen = [k for k in feats if (mode == "both" or k.startswith(f"hvac_{mode}"))
                  and float(np.mean(feats[k])) > least_K]
        chosen = chosen or [max(feats, key=lambda k: float(np.mean(feats[k])))]
        target_W = share * float(np.mean(power)) / len(chosen)
        p.truth[key] = {k: target_W / max(float(np.mean(feats[k])), 1e-3) for k in chosen}
        if (heat_below_C, cool_above_C) != (HVAC_SETPOINT_C, HVAC_SETPOINT_C):
            p.truth[key].update(hvac_heat_below_C=float(heat_below_C),
                                hvac_cool_above_C=float(cool_above_C))
        return power + sum(p.truth[key][k] * feats[k] for k in chosen)

    return add


def _surface_label(plan: _Plan, rng) -> None:
    """One surface rolls harder (as ``surface_rolling``), the map handed over has no surfaces
    and the recording carries a terrain classifier's labels (``_with_labels``): the rolling
    differs by surface (the map's own rolling coefficients too) and only the labels say
    where."""
    _surface_rolling(plan, rng)
    plan.truth["surface_label"] = plan.truth.pop("surface_rolling")
    plan.labels = True


TRIP_AMBIENT_SPAN_K = (3.0, 10.0)
"""Range of the span of a ``hvac_trip`` case's ambient temperature [K]: a trip of half an hour
meets a few kelvin (the day warming, a valley), not the 0-35 C of a season."""


def _hvac_trip(plan: _Plan, rng) -> None:
    """``hvac`` on a trip-like ambient: a walk over 3-10 K somewhere in 0-35 C. Where it stays
    on one side of the setpoint, the heating or cooling power is nearly constant over the
    trip and the constant loads, refitted, take it: only its variation is evidence (the
    detection limit that diagnosis states says how much of it a recording must carry)."""
    span = rng.uniform(*TRIP_AMBIENT_SPAN_K)
    low = rng.uniform(0.0, 35.0 - span)
    plan.ambient_C = (float(low), float(low + span))
    plan.power_effects.append(_hvac_adder("hvac_trip", "both", rng.uniform(0.08, 0.30),
                                          least_K=0.5))


HVAC_DEADBAND_K = (2.0, 6.0)
"""Range of the dead band of an ``hvac_deadband`` case's climate control [K]: it heats below
one set-point and cools above a higher one."""


def _hvac_deadband(plan: _Plan, rng) -> None:
    """``hvac`` of a climate control with a dead band: heating below 15-21 C, cooling above
    2-6 K higher, on a day whose ambient runs 3-6 K past both (a walk over 8-18 K). Fitted at
    one set-point, such a control's heating and cooling come out far too low."""
    heat = rng.uniform(15.0, 21.0)
    cool = heat + rng.uniform(*HVAC_DEADBAND_K)
    plan.ambient_C = (float(heat - rng.uniform(3.0, 6.0)), float(cool + rng.uniform(3.0, 6.0)))
    plan.power_effects.append(_hvac_adder("hvac_deadband", "both", rng.uniform(0.08, 0.30),
                                          least_K=0.5, heat_below_C=heat, cool_above_C=cool))


def _battery_resistance(plan: _Plan, rng) -> None:
    loss = rng.uniform(0.03, 0.10)
    _varied_load(plan, rng)

    def add(p, frame, power, _rng):
        k = loss / float(np.mean(power))  # loss fraction `loss` at the mean power
        p.truth["battery_resistance"] = {"battery_loss_per_W": k}
        return power + k * power**2

    plan.battery_effects.append(add)


def _battery_temperature(plan: _Plan, rng) -> None:
    plan.battery_cold = True
    _varied_load(plan, rng)
    loss = rng.uniform(0.04, 0.12)

    def add(p, frame, power, _rng):
        cold = np.maximum(0.0, BATTERY_WARM_C - frame["battery_C"].to_numpy(float))
        c = loss * float(np.mean(power)) / max(float(np.mean(cold * power**2)), 1e-9)
        p.truth["battery_temperature"] = {"battery_cold_loss_per_W_K": c}
        return power + c * cold * power**2

    plan.battery_effects.append(add)


def _varied_load(plan: _Plan, rng) -> None:
    """Stops and hills, so that the load varies: an in-battery loss ``k P^2`` differs from a
    rescaled model only by the curvature ``k (P - mean P)^2``, which a load steady within
    +-30 % makes smaller than a power meter's noise (the loss is then a mis-set coefficient,
    not something a recording can show)."""
    plan.sim_truth.setdefault("stop_every_s", float(rng.uniform(15.0, 40.0)))
    if plan.kind == "ground":
        plan.shape_route("hills")


def _drift(plan: _Plan, rng) -> None:
    if plan.kind == "marine":
        _drift_trend(plan, rng)
        return
    share = rng.uniform(0.05, 0.20)
    plan.power_effects.insert(0, _sizer(
        "drift", "drift_W", share,
        lambda frame: TERMS["drift"].features(_power_state(frame))[0]))
    plan.power_effects.append(lambda p, frame, power, _rng: power + _power_term_W(
        "drift", p.truth["drift"], frame))


TREND_SHAPES = ("linear", "decay", "step")
"""Shapes of a marine drift (``_drift_trend``, ``physics.terms.drift_shape_feature``)."""


def _drift_trend(plan: _Plan, rng) -> None:
    """A load that changes steadily through the run (a vessel's ancillary draw: pumps,
    heaters, a sonar as the water warms or the survey deepens): up or down by 15-35 % of the
    mean power over the run, as a line, a saturating exponential (time constant 5-50 % of
    the run: ``-drift_W exp(-t / tau)`` beside the constant loads) or a step at 20-80 % of
    the run. The truth's parameters are the drift term's (``physics.terms.drift_term``)."""
    shape = str(rng.choice(TREND_SHAPES))
    change = rng.uniform(0.15, 0.35) * (1.0 if rng.random() < 0.7 else -1.0)
    span = plan.duration_s
    tau = rng.uniform(0.05, 0.5) * span if shape == "decay" else span
    from_s = rng.uniform(0.2, 0.8) * span if shape == "step" else 0.0
    term = drift_term(shape, tau, from_s)
    # a rise that levels off is a decay with a negative coefficient
    sign = -1.0 if shape == "decay" else 1.0
    extra = ({"drift_from_s": from_s} if shape == "step"
             else {"drift_span_s" if shape == "linear" else "drift_tau_s": tau})

    def add(p, frame, power, _rng):
        feature = np.asarray(term.features(_power_state(frame))[0], float) + np.zeros(len(frame))
        swing = float(np.ptp(feature)) or 1.0
        drift_W = sign * change * float(np.mean(power)) / swing
        p.truth["drift"] = {"drift_W": drift_W, **extra}
        return power + drift_W * feature

    plan.power_effects.append(add)


ROLLING_TREND = (0.20, 0.50)
"""Range of a ``drift_rolling`` case's change of the rolling coefficient over the run, a share
of its value [-] (``_drift_rolling``)."""


def _drift_rolling(plan: _Plan, rng) -> None:
    """The rolling coefficient changing through the run (tyres warming and softening, a track
    wetting or drying): up or down by ``ROLLING_TREND`` of its value over the run, as a line,
    a saturating exponential (time constant 5-50 % of the run) or a step at 20-80 % of it.
    The truth's model carries the ``drift_rolling`` term, so the simulator drives it; its
    parameters are the term's (``physics.terms.drift_rolling_term``)."""
    shape = str(rng.choice(TREND_SHAPES))
    change = rng.uniform(*ROLLING_TREND) * (1.0 if rng.random() < 0.5 else -1.0)
    span = plan.duration_s
    tau = rng.uniform(0.05, 0.5) * span if shape == "decay" else span
    from_s = rng.uniform(0.2, 0.8) * span if shape == "step" else 0.0
    rolling_kg = float(_model(plan.truth_toml).get("rolling_kg", plan.mass_over_omega_kg))
    # over the run the shape moves by its swing: 1, except a decay's 1 - exp(-span / tau);
    # a decay falls, so a rise is a negative coefficient (a change that levels off)
    swing = 1.0 - float(np.exp(-span / tau)) if shape == "decay" else 1.0
    sign = -1.0 if shape == "decay" else 1.0
    delta_kg = sign * change * rolling_kg / swing
    _add_model_term(plan.truth_toml, "drift_rolling")
    _model(plan.truth_toml).update(drift_rolling_kg=delta_kg, drift_rolling_shape=shape,
                                   drift_rolling_tau_s=tau, drift_rolling_from_s=from_s)
    extra = ({"drift_from_s": from_s} if shape == "step"
             else {"drift_span_s" if shape == "linear" else "drift_tau_s": tau})
    plan.truth["drift_rolling"] = {"drift_rolling_kg": float(delta_kg), **extra}
    plan.shape_route("walks")  # a sidewalk robot's walks: rolling is over half its power


RECIPES: dict[str, Callable[[_Plan, np.random.Generator], None]] = {
    "ancillary": _ancillary, "sensor_rate": _sensor_rate, "hover": _hover, "rolling": _rolling,
    "surface_rolling": _surface_rolling, "aero_drag": _aero_drag, "grade": _grade,
    "inertia": _inertia, "regen": _regen, "turning": _turning, "wind": _wind,
    "payload": _payload, "hvac": _hvac, "battery_resistance": _battery_resistance,
    "battery_temperature": _battery_temperature, "drift": _drift,
    "surface_label": _surface_label, "hvac_trip": _hvac_trip, "drift_rolling": _drift_rolling,
    "hvac_deadband": _hvac_deadband,
}


def _sizer(term: str, coefficient: str, share: float, feature: Callable) -> Callable:
    """A power effect that sets ``coefficient`` so that the term's mean power is ``share`` of
    the mean simulated power (it changes no power itself; it runs before the term's adder)."""

    def size(p, frame, power, _rng):
        p.truth[term] = {coefficient: share * float(np.mean(power))
                         / max(float(np.mean(feature(frame))), 1e-9)}
        return power

    return size


def _power_state(frame: pd.DataFrame) -> MotionState:
    """The state of the time-only power terms: speed, sensor rate, elapsed time."""
    t = frame["t_s"].to_numpy(float)
    return MotionState(speed_mps=frame["v_mps"].to_numpy(float),
                       sensor_rate_Hz=frame["sensor_rate_Hz"].to_numpy(float),
                       channels={"elapsed_s": t - t[0]})


def _power_term_W(term: str, theta: dict[str, float], frame: pd.DataFrame) -> np.ndarray:
    """Power of one model term alone at the frame's samples [W] (the model's own maths)."""
    model = EnergyModel([TERMS[term]], theta)
    return np.asarray(model.power_W(_power_state(frame)), float) + np.zeros(len(frame))


def _mis_set(plan: _Plan, rng) -> None:
    """Null cases: a coefficient the model has is 10-20 % off (not a missing term): the
    ancillary loads, else the rolling coefficient (ground) or the hover power (aerial)."""
    factor = 1.0 + rng.uniform(0.10, 0.20) * (1 if rng.random() < 0.5 else -1)
    seen = plan.seen_toml
    if rng.random() < 0.5:
        for key in ("s0_W", "compute_W", "comm_W"):
            seen["ancillary"][key] *= factor
    elif plan.kind == "ground":
        _model(seen)["rolling_kg"] = plan.mass_over_omega_kg * factor
    elif plan.kind == "aerial":
        seen["robot"]["hover_W"] *= factor
    else:  # marine: the drag through the water
        seen["robot"]["drag_coeff_kg_per_m"] *= factor
