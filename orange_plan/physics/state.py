"""The motion and environment state the physics terms are evaluated on."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from orange_plan.errors import InputError
from orange_plan.physics import ops

Array = Any  # numpy array, float or CasADi symbol


@dataclass(frozen=True)
class MotionState:
    """Motion, terrain and environment at a sample (time domain) or over a straight step.

    Every field broadcasts against the others (numpy) or is a CasADi symbol/number.

    Parameters
    ----------
    speed_mps : ground speed along the path [m/s]
    cos_t, sin_t : cosine and sine of the grade angle [-] (uphill positive sine)
    dir_x, dir_y : unit horizontal direction of travel (x east, y north) [-]
    wind_x_mps, wind_y_mps : wind (or water current) velocity vector [m/s]
    crr : rolling-resistance coefficient where the robot is [-]
    accel_mps2 : longitudinal acceleration [m/s^2]
    yaw_rate_radps : heading rate [rad/s]
    sensor_rate_Hz : sensor operating frequency [Hz]
    surface_code : integer code of the surface under the robot, -1 for "default ground"
    hvac_W : cabin heating / air-conditioning electrical power, measured or planned [W]
    heater_request_W : requested cabin heating power (a climate-control demand, not a meter) [W]
    elapsed_s : time since the start of the trip or mission (drivetrain warm-up) [s]
    """

    speed_mps: Array
    cos_t: Array = 1.0
    sin_t: Array = 0.0
    dir_x: Array = 1.0
    dir_y: Array = 0.0
    wind_x_mps: Array = 0.0
    wind_y_mps: Array = 0.0
    crr: Array = 0.0
    accel_mps2: Array = 0.0
    yaw_rate_radps: Array = 0.0
    sensor_rate_Hz: Array = 0.0
    surface_code: Array = -1
    hvac_W: Array = 0.0
    heater_request_W: Array = 0.0
    elapsed_s: Array = 0.0

    def with_(self, **changes) -> MotionState:
        """A copy with some fields replaced."""
        return replace(self, **changes)

    def air_velocity(self):
        """Air (or water) velocity relative to the robot, ``a = v u - w`` [m/s]."""
        ax = self.speed_mps * self.dir_x - self.wind_x_mps
        ay = self.speed_mps * self.dir_y - self.wind_y_mps
        return ax, ay

    def validate(self) -> MotionState:
        """Check a numeric state (not symbolic): finite, speed >= 0, crr in [0, 1].

        Raises
        ------
        InputError
            Naming the first offending field and value.
        """
        for f in fields(self):
            value = getattr(self, f.name)
            if ops.is_symbolic(value):
                continue
            arr = np.asarray(value, dtype=float)
            if not np.all(np.isfinite(arr)):
                raise InputError(f"MotionState.{f.name} holds a non-finite value")
        _check_range("speed_mps", self.speed_mps, 0.0, np.inf)
        _check_range("crr", self.crr, 0.0, 1.0)
        _check_range("cos_t", self.cos_t, 0.0, 1.0)
        _check_range("sin_t", self.sin_t, -1.0, 1.0)
        _check_range("sensor_rate_Hz", self.sensor_rate_Hz, 0.0, np.inf)
        _check_range("hvac_W", self.hvac_W, 0.0, np.inf)
        _check_range("heater_request_W", self.heater_request_W, 0.0, np.inf)
        _check_range("elapsed_s", self.elapsed_s, 0.0, np.inf)
        return self


def _check_range(name: str, value, lo: float, hi: float) -> None:
    if ops.is_symbolic(value):
        return
    arr = np.asarray(value, dtype=float)
    bad = (arr < lo) | (arr > hi)
    if np.any(bad):
        first = arr[bad].ravel()[0]
        raise InputError(f"MotionState.{name} = {first:g} is outside [{lo:g}, {hi:g}]")
