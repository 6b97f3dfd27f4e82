"""The motion and environment state the physics terms are evaluated on."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from orange_plan.errors import InputError
from orange_plan.physics import ops

Array = Any  # numpy array, float or CasADi symbol

CHANNELS: dict[str, Channel] = {}
"""Every declared channel by name (declaring a ``Channel`` registers it)."""


@dataclass(frozen=True)
class Channel:
    """A named operating condition that a term reads from ``MotionState.channels``.

    The set is open: a term declares the channels it needs (``Term.channels``), a recording
    fills each declared channel from its column of the same name (``telemetry.state``), and
    ``MotionState.validate`` checks the declared range. A new condition is one declaration,
    not an edit of MotionState, its validation and the recording reader.

    Parameters
    ----------
    name : unit-suffixed name, also the recording column (``hvac_W``)
    lo, hi : allowed range of a value
    description : one line, with the unit
    """

    name: str
    lo: float = -np.inf
    hi: float = np.inf
    description: str = ""

    def __post_init__(self):
        CHANNELS[self.name] = self


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
    channels : further operating conditions by ``Channel`` name (cabin HVAC power, elapsed
        time...); an absent channel reads 0
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
    channels: Mapping[str, Array] = field(default_factory=dict)

    def channel(self, name: str) -> Array:
        """The value of channel ``name`` (0 where the state does not carry it)."""
        return self.channels.get(name, 0.0)

    def with_(self, **changes) -> MotionState:
        """A copy with some fields or channels replaced (channels by their name)."""
        own = {f.name for f in fields(self)}
        extra = {k: v for k, v in changes.items() if k not in own}
        unknown = [k for k in extra if k not in CHANNELS]
        if unknown:
            raise TypeError(f"MotionState has no field or channel '{unknown[0]}'")
        fixed = {k: v for k, v in changes.items() if k in own}
        if extra:
            fixed["channels"] = {**fixed.get("channels", self.channels), **extra}
        return replace(self, **fixed)

    def values(self) -> dict[str, Array]:
        """Every field and channel by name (channels flattened beside the fields)."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "channels"}
        return {**out, **self.channels}

    def take(self, index, n: int) -> MotionState:
        """The samples ``index`` (mask, slice or integers) of a per-sample state of ``n``
        samples; scalar fields are broadcast to ``n`` first."""
        picked = {k: np.broadcast_to(np.asarray(v), (n,))[index] for k, v in self.values().items()}
        return MotionState.from_values(picked)

    @staticmethod
    def concat(states: Sequence[MotionState], sizes: Sequence[int]) -> MotionState:
        """Per-sample states of ``sizes`` samples each, one after the other (a channel one
        state lacks reads 0 there)."""
        names = dict.fromkeys(k for s in states for k in s.values())
        return MotionState.from_values({
            k: np.concatenate([np.broadcast_to(np.asarray(s.values().get(k, 0.0)), (n,))
                               for s, n in zip(states, sizes)])
            for k in names})

    @staticmethod
    def from_values(values: Mapping[str, Array]) -> MotionState:
        """A state from field and channel values by name (the inverse of ``values``)."""
        return MotionState(**{k: v for k, v in values.items() if k not in CHANNELS}).with_(
            **{k: v for k, v in values.items() if k in CHANNELS})

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
        for name, value in self.values().items():
            if ops.is_symbolic(value):
                continue
            arr = np.asarray(value, dtype=float)
            if not np.all(np.isfinite(arr)):
                raise InputError(f"MotionState.{name} holds a non-finite value")
        _check_range("speed_mps", self.speed_mps, 0.0, np.inf)
        _check_range("crr", self.crr, 0.0, 1.0)
        _check_range("cos_t", self.cos_t, 0.0, 1.0)
        _check_range("sin_t", self.sin_t, -1.0, 1.0)
        _check_range("sensor_rate_Hz", self.sensor_rate_Hz, 0.0, np.inf)
        for name, value in self.channels.items():
            if name in CHANNELS:
                _check_range(name, value, CHANNELS[name].lo, CHANNELS[name].hi)
        return self


def _check_range(name: str, value, lo: float, hi: float) -> None:
    if ops.is_symbolic(value):
        return
    arr = np.asarray(value, dtype=float)
    bad = (arr < lo) | (arr > hi)
    if np.any(bad):
        first = arr[bad].ravel()[0]
        raise InputError(f"MotionState.{name} = {first:g} is outside [{lo:g}, {hi:g}]")
