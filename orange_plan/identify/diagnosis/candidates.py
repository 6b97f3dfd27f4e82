"""The candidates diagnosis tries (``candidates``): for each, when it applies to a recording,
its columns (``effects``, ``labels``) and what a person would plot the residual against.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from orange_plan.identify.diagnosis.design import (
    LABEL_CANDIDATE,
    Candidate,
    Design,
    _surfaces_seen,
)
from orange_plan.identify.diagnosis.effects import (
    _drift_effect,
    _drift_rolling_effect,
    _needs_mass,
    _payload_effect,
    _surface_effect,
    _term_effect,
    _wind_effect,
)
from orange_plan.identify.diagnosis.hvac_effects import _hvac_ambient_effect
from orange_plan.identify.diagnosis.labels import _label_effect, _needs_labels, surface_labels
from orange_plan.physics.terms import TERMS

TERM_CANDIDATES = ("ancillary", "sensor_rate", "hover", "rolling", "surface_rolling",
                   "aero_drag", "grade", "inertia", "regen", "turning", "turning_torque",
                   "hvac", "hvac_ambient", "heater", "battery_resistance",
                   "battery_temperature", "drift", "drift_rolling")
"""Candidates that are terms of ``physics.terms`` (besides ``wind`` and ``payload``)."""


def _applies_term(term_id: str, needs: Callable | None = None):
    def applies(d: Design):
        if term_id in d.base.term_ids:
            return "in the model"
        if term_id == "turning_torque" and "turning" in d.base.term_ids:
            return "turning is in the model"
        term = TERMS.get(term_id)
        for ch in (term.channels if term else ()):
            if ch.name not in d.columns_of and ch.name != "elapsed_s":
                return f"the recording has no {ch.name} column"
        return needs(d) if needs else None

    return applies


def _varies(column: str, spread: float):
    def check(d: Design):
        values = d.frame[column].to_numpy(float) if column in d.columns_of else None
        if values is None:
            return f"the recording has no {column} column"
        if np.nanmax(values) - np.nanmin(values) < spread:
            return f"{column} varies by less than {spread:g}"
        return None

    return check


def _needs_hills(d: Design):
    return None if np.ptp(np.asarray(d.state.sin_t)) > 0.01 else "the recording is flat"


def _needs_landed(d: Design):
    if d.scenario.robot.kind != "aerial":
        return "not an aerial robot"
    return None if (~d.airborne).mean() > 0.02 else "no landed period to tell hover from idle"


def _needs_long_run(d: Design):
    """A warm-up with a 20-minute time constant is a straight line over a few minutes, which
    slow noise (a breeze, a battery settling) draws as well: only runs of half the time
    constant or more can show it."""
    from orange_plan.physics.terms import DRIFT_TAU_S

    span = float(d.t_s[-1] - d.t_s[0])
    return None if span >= 0.5 * DRIFT_TAU_S else f"the run ({span:.0f} s) is too short to " \
        f"show a warm-up of time constant {DRIFT_TAU_S:.0f} s"


def _needs_rolling_long_run(d: Design):
    """A rolling coefficient that changes needs a rolling term to change, and a long run
    (``_needs_long_run``)."""
    if "rolling_kg" not in d.base.names or d.base.coefficient("rolling_kg") <= 0:
        return "no rolling term whose coefficient could change"
    return _needs_long_run(d)


def _needs_cold_cells(d: Design):
    temps = d.frame["battery_C"].to_numpy(float)
    return None if np.nanmin(temps) < 20.0 else "the cells never ran cold (< 20 C)"


def _needs_surfaces(d: Design):
    if "rolling_kg" not in d.base.names:
        return "no rolling term to differ by surface"
    if not _surfaces_seen(d):
        return "the recording spends no time on a map surface"
    return None


def _needs_wind(d: Design):
    if {"wind_mps", "wind_from_deg"} <= d.columns_of:
        return "the wind is recorded"
    if "drag_kg_per_m" not in d.base.names or d.base.coefficient("drag_kg_per_m") <= 0:
        return "no drag term for a wind to act on"
    # at the scenario's drag coefficient: the refit one may have grown to take up something
    # else (a slope met in one direction), which is no evidence of a wind
    i = d.base.names.index("drag_kg_per_m")
    drag_W = d.columns[:, i] * d.prior_mean[i]
    if np.mean(np.abs(drag_W)) < d.settings.min_drag_share * d.mean_power_W:
        return "drag is negligible at these speeds: a wind could not show"
    if not {"x_m", "y_m"} <= d.columns_of:
        return "no positions: the heading relative to a wind is unknown"
    return None


def _needs_braking(d: Design):
    """Braking in the model, or a wheeled robot's decelerations that a missing inertia would
    make braking (a car's road-load model brakes only downhill)."""
    force = np.asarray(d.base.traction_force_N(d.state))
    slows = (d.scenario.robot.kind == "ground" and "inertia" not in d.base.term_ids
             and np.any(np.asarray(d.state.accel_mps2) < 0))
    return None if np.any(force < 0) or slows else "the traction force never goes negative"


def _feature(values_of: Callable, label: str):
    return lambda d: (np.broadcast_to(np.asarray(values_of(d), float), (d.n,)), label)


def _column(name: str):
    return lambda d: d.frame[name].to_numpy(float)


_NEEDS: dict[str, Callable] = {
    "sensor_rate": _varies("sensor_rate_Hz", 1.0),
    "hover": _needs_landed,
    "surface_rolling": _needs_surfaces,
    "grade": _needs_hills,
    "regen": _needs_braking,
    "hvac_ambient": _varies("ambient_C", 3.0),
    "battery_temperature": _needs_cold_cells,
    "drift": _needs_long_run,
    "drift_rolling": _needs_rolling_long_run,
}
_FEATURES: dict[str, tuple[Callable, str]] = {
    "ancillary": (lambda d: d.t_s, "time since start [s]"),
    "sensor_rate": (_column("sensor_rate_Hz"), "sensor rate [Hz]"),
    "hover": (lambda d: d.airborne, "airborne [-]"),
    "rolling": (lambda d: d.state.speed_mps, "speed [m/s]"),
    "surface_rolling": (lambda d: d.state.surface_code, "surface code (-1: default ground)"),
    "aero_drag": (lambda d: d.state.speed_mps, "speed [m/s]"),
    "grade": (lambda d: d.state.sin_t, "grade sin(theta) [-]"),
    "inertia": (lambda d: d.state.accel_mps2, "acceleration [m/s^2]"),
    "regen": (lambda d: np.asarray(d.base.traction_force_N(d.state)), "lumped traction force [N]"),
    "turning": (lambda d: np.abs(d.state.yaw_rate_radps), "|yaw rate| [rad/s]"),
    "turning_torque": (lambda d: np.abs(d.state.yaw_rate_radps), "|yaw rate| [rad/s]"),
    "hvac": (_column("hvac_W"), "HVAC power [W]"),
    "hvac_ambient": (_column("ambient_C"), "ambient temperature [C]"),
    "heater": (_column("heater_request_W"), "requested heating [W]"),
    "battery_resistance": (lambda d: d.base.load_power_W(d.state), "load power [W]"),
    "battery_temperature": (_column("battery_C"), "battery temperature [C]"),
    "drift": (lambda d: d.t_s, "time since start [s]"),
    "drift_rolling": (lambda d: d.t_s, "time since start [s]"),
    "payload": (lambda d: d.t_s, "time since start [s]"),
    LABEL_CANDIDATE: (lambda d: surface_labels(d).code, "surface label (-1: the reference)"),
    "wind": (lambda d: np.degrees(np.arctan2(d.state.dir_x, d.state.dir_y)) % 360.0,
             "heading [deg from north]"),
}


def candidates() -> list[Candidate]:
    """Every candidate diagnosis tries (the method: ``identify.diagnosis``)."""
    special = {"surface_rolling": _surface_effect, "drift": _drift_effect,
               "drift_rolling": _drift_rolling_effect, "hvac_ambient": _hvac_ambient_effect}
    out = [Candidate(t, _applies_term(t, _NEEDS.get(t)), special.get(t) or _term_effect(t),
                     _feature(*_FEATURES[t])) for t in TERM_CANDIDATES]
    out.append(Candidate("payload", _needs_mass, _payload_effect, _feature(*_FEATURES["payload"])))
    out.append(Candidate("wind", _needs_wind, _wind_effect, _feature(*_FEATURES["wind"])))
    out.append(Candidate(LABEL_CANDIDATE, _needs_labels, _label_effect,
                         _feature(*_FEATURES[LABEL_CANDIDATE])))
    return out


def candidate_columns(d: Design, pool: list[Candidate] | None = None):
    """Every applicable candidate's columns on the whole recording (non-linear parameters
    estimated on the baseline's residual): ``(columns (n, m), owner id of each column)``.
    What a generic sparse regression is given in ``bench diagnose``."""
    resid = d.target - d.columns @ d.base.theta
    everything = np.ones(d.n, bool)
    cols, owners = [], []
    for cand in pool or candidates():
        if cand.applies(d) is None:
            eff = cand.effect(d, resid, everything)
            cols.append(eff.columns)
            owners += [cand.id] * eff.columns.shape[1]
    return (np.hstack(cols) if cols else np.zeros((d.n, 0))), owners
