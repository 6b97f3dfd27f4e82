"""Mission rules every planner applies to its answers (one place, so they all agree).

The time limit (``mission.time_limit_s``): an answer whose planned mission time
exceeds it is not feasible, whatever its energy. ``check_time_limit`` decides it and words the
reason; ``range``, ``reach``, the speed optimiser (and the tour planner) call it with their
planned mission time: stops included, and the driven speed profile's where they have one
(``physics.pathcost.path_energy`` with ``accel_max_mps2``).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TimeLimitCheck:
    """A planned mission time against the scenario's limit.

    Attributes
    ----------
    duration_s : planned mission time, stops included [s]
    time_limit_s : ``mission.time_limit_s``, None when the scenario sets none [s]
    """

    duration_s: float
    time_limit_s: float | None

    @property
    def within(self) -> bool:
        """True when there is no limit or the mission time does not exceed it."""
        return self.time_limit_s is None or self.duration_s <= self.time_limit_s

    @property
    def reason(self) -> str | None:
        """None within the limit, else one line saying by how much it is exceeded."""
        if self.within:
            return None
        return (f"mission time {_seconds(self.duration_s)} s exceeds mission.time_limit_s = "
                f"{_seconds(self.time_limit_s)} s")


def _seconds(value: float) -> str:
    """Whole seconds with thousands separators; a value under 10 s with its own digits (a
    0.0001 s limit must not read as 0 s)."""
    return f"{value:,.0f}" if abs(value) >= 10 else f"{value:.3g}"


def check_time_limit(duration_s: float, time_limit_s: float | None) -> TimeLimitCheck:
    """Whether a planned mission time ``duration_s`` [s] fits ``time_limit_s`` [s] (None: no
    limit). The rule: feasible iff ``time_limit_s is None or duration_s <= time_limit_s``."""
    return TimeLimitCheck(float(duration_s), None if time_limit_s is None else float(time_limit_s))
