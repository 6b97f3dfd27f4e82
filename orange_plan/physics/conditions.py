"""Operating conditions of one mission: what energy depends on besides the robot and the map.

One value travels from the scenario to path costs, roadmap weights, the speed problem and the
simulator, so that planning and simulation cannot disagree on the duty cycle, the sensor rate or
the wind (a session's measured wind is ``conditions.with_wind(...)``, nothing else changes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from orange_plan.errors import InputError


@dataclass(frozen=True)
class Conditions:
    """Duty cycle, sensor rate, wind (or water current) and temperature of a mission.

    Attributes
    ----------
    duty_cycle : D, the fraction of mission time spent moving, in (0, 1] [-]
    sensor_rate_Hz : sensor frame rate, >= 0 [Hz]
    wind_xy_mps : mean wind or water current (x east, y north) [m/s]
    ambient_C : ambient temperature [degC]; the battery is taken to sit at it too (the
        ``ambient_C`` and ``battery_C`` channels of a planned state, ``channels``)
    elapsed_s : the mission time a planned state's drift is charged at, >= 0 [s]: its worst
        over the mission's horizon (``physics.horizon``; set by ``Context``), 0 by default
    """

    duty_cycle: float
    sensor_rate_Hz: float = 0.0
    wind_xy_mps: tuple[float, float] = (0.0, 0.0)
    ambient_C: float = 20.0
    elapsed_s: float = 0.0

    def __post_init__(self):
        # checked here, the one place they are built, so no consumer re-validates them
        if not (math.isfinite(self.duty_cycle) and 0.0 < self.duty_cycle <= 1.0):
            raise InputError(f"duty_cycle must be in (0, 1], got {self.duty_cycle}")
        if not (math.isfinite(self.sensor_rate_Hz) and self.sensor_rate_Hz >= 0.0):
            raise InputError(f"sensor_rate_Hz must be a finite value >= 0, got {self.sensor_rate_Hz}")
        wind = tuple(float(w) for w in self.wind_xy_mps)
        if len(wind) != 2 or not all(math.isfinite(w) for w in wind):
            raise InputError(f"wind_xy_mps must be two finite numbers [m/s], got {self.wind_xy_mps}")
        object.__setattr__(self, "duty_cycle", float(self.duty_cycle))
        object.__setattr__(self, "sensor_rate_Hz", float(self.sensor_rate_Hz))
        if not (math.isfinite(self.ambient_C) and -90.0 <= self.ambient_C <= 150.0):
            raise InputError(f"ambient_C must be in [-90, 150] degC, got {self.ambient_C}")
        object.__setattr__(self, "wind_xy_mps", wind)
        object.__setattr__(self, "ambient_C", float(self.ambient_C))
        if not (math.isfinite(self.elapsed_s) and self.elapsed_s >= 0.0):
            raise InputError(f"elapsed_s must be a finite time >= 0 s, got {self.elapsed_s}")
        object.__setattr__(self, "elapsed_s", float(self.elapsed_s))

    @property
    def channels(self) -> dict[str, float]:
        """Operating-condition channels of a planned state (``physics.state.Channel``):
        the temperatures that temperature-dependent terms read, and the mission time a drift
        is charged at (a recording's own elapsed time replaces it: ``telemetry.state``)."""
        return {"ambient_C": self.ambient_C, "battery_C": self.ambient_C,
                "elapsed_s": self.elapsed_s}

    @classmethod
    def of(cls, scenario) -> Conditions:
        """The scenario's conditions: mission duty cycle, sensor rate, environment wind."""
        return cls(scenario.mission.duty_cycle, scenario.ancillary.sensor_rate_Hz,
                   scenario.environment.wind_xy_mps, scenario.environment.ambient_C)

    def with_elapsed(self, elapsed_s: float) -> Conditions:
        """The same conditions with a drift charged at mission time ``elapsed_s`` [s]."""
        return replace(self, elapsed_s=elapsed_s)

    def with_wind(self, wind_xy_mps) -> Conditions:
        """The same conditions under another wind or current [m/s]."""
        return replace(self, wind_xy_mps=tuple(wind_xy_mps))
