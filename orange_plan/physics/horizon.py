"""The mission time at which planning charges a drift: its worst over the mission's horizon.

A ``drift`` (``physics.terms.drift_term``, ``drift_rolling_term``) changes with the time since
the start of the mission, which a roadmap edge or a path step does not know: the same edge
may be driven early or late. Planning therefore evaluates every term that reads the elapsed
time at one mission time ``t*``, the one in ``[0, T]`` where the robot's mean power is
largest, ``T`` the mission's horizon (``mission_horizon_s``). For one drift of a monotone shape
that is its largest value over the mission: a cold-start decay is charged at ``t = 0``, a
rising line at ``T``, a step at ``T`` if it comes within the horizon and not at all if it
falls. The recording's own elapsed time is untouched: only planned states read ``t*``
(``Conditions.elapsed_s``).
"""

from __future__ import annotations

import math

import numpy as np

from orange_plan.errors import InputError
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.state import MotionState
from orange_plan.physics.terms import ELAPSED_S

HORIZON_POINTS = 65
"""Mission times tried in ``[0, T]``: the ends, where one monotone drift is at its worst, and
points between them for a model with more than one drift (their sum need not be monotone)."""


def reads_elapsed_time(model: EnergyModel) -> bool:
    """Whether some term of ``model`` depends on the time since the start (a drift)."""
    return any(ELAPSED_S in t.channels for t in model.terms)


def without_elapsed_time(model: EnergyModel) -> EnergyModel:
    """``model`` without its time-dependent terms (what the horizon is measured with)."""
    kept = [t for t in model.terms if ELAPSED_S not in t.channels]
    return model.with_terms(kept, {})


def _reference_state(speed_mps: float, default_crr: float, channels) -> MotionState:
    """Level default ground at ``speed_mps``: the state the worst time is judged on."""
    return MotionState(speed_mps=speed_mps, crr=default_crr, channels=dict(channels))


def mean_power_W(model: EnergyModel, state: MotionState, duty_cycle: float):
    """Mission-mean power [W]: the power terms all the time, traction for the moving share."""
    return model.ancillary_power_W(state) + duty_cycle * model.traversal_power_W(state)


def mission_horizon_s(scenario, model: EnergyModel, default_crr: float, conditions) -> float:
    """The longest the mission can last [s]: ``mission.time_limit_s``, or else the time the
    usable battery energy lasts at the slowest speed without the drift.

    Without the drift is the longer of the two for a rising drift (which empties the battery
    sooner), so the horizon does not cut a rising drift short.

    Raises
    ------
    InputError
        No time limit and a model that draws no power: the mission's time is unbounded.
    """
    limit = scenario.mission.time_limit_s
    if limit is not None:
        return float(limit)
    state = _reference_state(scenario.robot.v_min_mps, default_crr, conditions.channels)
    power = float(mean_power_W(without_elapsed_time(model), state, conditions.duty_cycle))
    if not (math.isfinite(power) and power > 0.0):
        raise InputError(f"{scenario.name}: the model draws {power:.3g} W without its drift, so "
                         "the time over which the drift is charged is unbounded; set "
                         "mission.time_limit_s")
    return float(scenario.battery.usable_J) / power


def worst_elapsed_s(model: EnergyModel, horizon_s: float, speed_mps: float, default_crr: float,
                    conditions) -> float:
    """The mission time in ``[0, horizon_s]`` at which ``model``'s mean power is largest [s]
    (0 for a model without time-dependent terms, and on a tie: the earliest such time).

    Raises
    ------
    InputError
        A horizon that is negative or not finite.
    """
    if not reads_elapsed_time(model):
        return 0.0
    if not (math.isfinite(horizon_s) and horizon_s >= 0.0):
        raise InputError(f"mission horizon = {horizon_s!r} s must be a finite time >= 0")
    times = np.linspace(0.0, horizon_s, HORIZON_POINTS)
    state = _reference_state(speed_mps, default_crr, {**conditions.channels, ELAPSED_S.name: times})
    power = np.broadcast_to(np.asarray(mean_power_W(model, state, conditions.duty_cycle), float),
                            times.shape)
    return float(times[int(np.argmax(power))])


def planning_elapsed_s(scenario, model: EnergyModel, default_crr: float, conditions) -> float:
    """The mission time planning evaluates ``model``'s drift at (module docstring) [s]."""
    if not reads_elapsed_time(model):
        return 0.0
    horizon = mission_horizon_s(scenario, model, default_crr, conditions)
    return worst_elapsed_s(model, horizon, scenario.robot.v_min_mps, default_crr, conditions)
