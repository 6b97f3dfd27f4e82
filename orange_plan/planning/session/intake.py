"""Telemetry intake of a mission session: a batch of samples checked, then taken in.

``validated_batch`` refuses what cannot be a robot's telemetry (one line each): a missing
column, a value that is not a finite number, time negative or not increasing, a position
off the map (``world.positions.check_on_map``, the rule predict and calibrate apply).
``Intake`` keeps what the samples taught: the battery energy used, the online estimator,
the trail and the area sensed, and the estimator's window of recent batches. A batch with a
position outside the map's free space counts its energy and time but teaches nothing
(``Intake.take``): a localisation glitch must not stretch the distance the energy per metre
and the remaining range are taken over, nor mark area as sensed.

Energy used is ``sum P dt`` with regeneration: a negative power sample (a robot braking or
going downhill) gives energy back, but a battery cannot hold more than when full, so the
cumulative energy used never goes below 0 (``physics.battery.energy_used_after``), and the
spare energy a decision counts on never exceeds the battery's.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
import pandas as pd
import shapely

from orange_plan.errors import InputError
from orange_plan.identify.online import OnlineEstimator
from orange_plan.identify.soc import SocCapacity
from orange_plan.physics.battery import energy_used_after
from orange_plan.physics.state import MotionState
from orange_plan.planning.coverage import footprint
from orange_plan.telemetry.recording import recording_from_frame
from orange_plan.telemetry.state import recording_state
from orange_plan.world.positions import check_on_map

CONTEXT_ROWS = 8
"""Earlier samples prepended to a batch so speeds and yaw rates derived from positions
(centred differences over ``SMOOTH_WINDOW_S``) are continuous across batches."""


def validated_batch(samples, world, t_last: float | None) -> pd.DataFrame:
    """A batch of samples as a DataFrame with numeric columns and ``power_W``.

    Parameters
    ----------
    samples : pandas DataFrame or list of dicts (``MissionSession.feed``)
    world : the mission's World (positions must lie on its map)
    t_last : time of the previous batch's last sample [s], None before the first

    Raises
    ------
    InputError
        One line: a missing column, a non-numeric or non-finite value in a needed column,
        a negative time, time not increasing (within the batch or against the previous
        batch), a position off the map.
    """
    frame = _as_frame(samples)
    power = ["power_W"] if "power_W" in frame else ["voltage_V", "current_A"]
    needed = ["t_s", *power, "x_m", "y_m"]
    missing = [c for c in needed if c not in frame]
    if missing:
        raise InputError(f"samples: missing column(s) {missing} (need t_s, power_W or "
                         "voltage_V and current_A, x_m, y_m)")
    for col in needed:
        frame[col] = _finite_column(frame, col)
    _check_time(frame["t_s"].to_numpy(float), t_last)
    check_on_map(world, frame["x_m"].to_numpy(float), frame["y_m"].to_numpy(float),
                 "samples", "row")
    if "power_W" not in frame:
        frame["power_W"] = frame["voltage_V"] * frame["current_A"]
    return frame


def _as_frame(samples) -> pd.DataFrame:
    if isinstance(samples, pd.DataFrame):
        frame = samples.reset_index(drop=True).copy()
    else:
        try:
            frame = pd.DataFrame(list(samples))
        except (TypeError, ValueError) as exc:
            raise InputError(f"samples must be a DataFrame or a list of dicts ({exc})") from None
    if len(frame) == 0:
        raise InputError("samples: the batch is empty")
    return frame


def _finite_column(frame: pd.DataFrame, col: str):
    """The column as floats; InputError naming the first row that is not a finite number."""
    floats = frame[col].dtype == np.float64  # JSON numbers: no text to convert
    values = (frame[col].to_numpy() if floats
              else pd.to_numeric(frame[col], errors="coerce").to_numpy(float))
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise InputError(f"samples: {col} is not a finite number at row {int(bad[0])} "
                         f"({frame[col].iloc[int(bad[0])]!r})")
    return frame[col] if floats else values


def _check_time(t: np.ndarray, t_last: float | None) -> None:
    """Mission time starts at 0 and only goes forward."""
    negative = np.flatnonzero(t < 0)
    if negative.size:
        i = int(negative[0])
        raise InputError(f"samples: t_s is negative at row {i} ({t[i]:g} s); mission time "
                         "starts at 0 s")
    prev = np.r_[t_last if t_last is not None else -np.inf, t[:-1]]
    back = np.flatnonzero(t <= prev)
    if back.size:
        i = int(back[0])
        raise InputError(f"samples: t_s does not increase at row {i} ({t[i]:g} s after "
                         f"{prev[i]:g} s)")


@dataclass
class Batch:
    """One telemetry batch as the estimator's window keeps it."""

    duration_s: float
    distance_m: float
    measured_J: float
    state: MotionState
    dt: np.ndarray
    wind_dt_m: tuple[float, float]  # time integrals of the wind (the window's mean wind)
    planned_J: float | None = None  # this motion's energy under the plan's model (lazily)


class Intake:
    """What the samples have taught a session so far.

    Parameters
    ----------
    model : the scenario's energy model (the online estimator's prior)
    usable_J : the scenario's usable battery energy [J]
    memory_s, window_s : the online estimator's forgetting time and window [s]

    Attributes
    ----------
    estimator : the online estimator (coefficients, covariance, energy per metre)
    soc : the battery capacity the state of charge shows
    window : the last ``window_s`` of batches
    trail_xy_m : reported positions, the plan's start first (n, 2) [m]
    last_free_xy_m : the last of them in the map's free space [m]
    covered : area sensed so far
    time_s : time of the last sample (the plan's start before any) [s]
    t_last : time of the last sample, None before the first [s]
    energy_used_J : battery energy used so far, never below 0 [J]
    last_batch_J, last_batch_s : battery energy the last batch drew [J] and its duration [s]
        (the robot flies about as long again before the next decision reaches it)
    """

    def __init__(self, model, usable_J: float, *, memory_s: float, window_s: float):
        self.estimator = OnlineEstimator(model, usable_J, memory_s=memory_s, window_s=window_s)
        self.window_s = float(window_s)
        self.soc = SocCapacity()
        self.window: deque[Batch] = deque()
        self.history = pd.DataFrame()
        self.covered = shapely.GeometryCollection()
        self.t_last: float | None = None
        self.last_batch_J = self.last_batch_s = 0.0
        self.start_at(np.zeros((1, 2)), 0.0, 0.0)

    def start_at(self, xy_m, energy_used_J: float, time_s: float) -> None:
        """Where the plan starts, before any sample: position [m], energy already used [J]
        (held at 0 from below), time [s]."""
        self.trail_xy_m = np.asarray(xy_m, float).reshape(-1, 2)
        self.last_free_xy_m = self.trail_xy_m[-1]
        self.energy_used_J = max(float(energy_used_J), 0.0)
        self.time_s = float(time_s)

    @property
    def position_xy_m(self) -> tuple[float, float]:
        return (float(self.trail_xy_m[-1, 0]), float(self.trail_xy_m[-1, 1]))

    def take(self, frame: pd.DataFrame, ctx) -> bool:
        """Energy, time and trail from a validated batch; the estimator, its window and the
        sensed area too when every position is where the map allows the robot to be.

        Returns
        -------
        bool
            True when every position is in the map's free space (``World.is_free``). A batch
            with one that is not still counts its energy and time (the battery drained all
            the same), but its motion is not the robot's as far as the map can tell: it
            teaches the estimator nothing, stays out of the window and of the context later
            batches' speeds are derived from, and senses no area.
        """
        t = frame["t_s"].to_numpy(float)
        xy = frame[["x_m", "y_m"]].to_numpy(float)
        dt = np.diff(np.r_[t[0] if self.t_last is None else self.t_last, t])
        power = frame["power_W"].to_numpy(float)
        used = energy_used_after(self.energy_used_J, power, dt)
        if "soc" in frame:
            self.soc.add(used, pd.to_numeric(frame["soc"], errors="coerce").to_numpy(float))
        # what the robot draws until the next decision can reach it: about one batch more
        self.last_batch_J = max(float(power @ dt), 0.0)
        self.last_batch_s = float(np.sum(dt))
        self.energy_used_J = float(used[-1])
        trusted = bool(np.all(ctx.world.is_free(xy[:, 0], xy[:, 1])))
        if trusted:
            self._learn(frame, ctx, dt)
            self._sense(xy, ctx)
        self.trail_xy_m = np.vstack([self.trail_xy_m, xy])
        self.time_s = float(t[-1])
        self.t_last = float(t[-1])
        return trusted

    def _learn(self, frame: pd.DataFrame, ctx, dt: np.ndarray) -> None:
        """The estimator and its window from a batch, its speeds and yaw rates derived with
        the last ``CONTEXT_ROWS`` samples before it."""
        history = pd.concat([self.history, frame], ignore_index=True)
        self.history = history.tail(CONTEXT_ROWS).reset_index(drop=True)
        if len(history) < 2:
            return
        t = frame["t_s"].to_numpy(float)
        context = history.tail(len(frame) + CONTEXT_ROWS)
        rec = recording_from_frame(context, "samples")
        state = recording_state(rec, ctx.world, conditions=ctx.conditions)
        state = state.take(slice(len(rec.frame) - len(frame), None), len(rec.frame))
        state = state.with_(elapsed_s=t - float(history["t_s"].iloc[0]))
        power = frame["power_W"].to_numpy(float)
        self.estimator.update(state, power, dt)
        speed = np.asarray(state.speed_mps, float) * np.ones(len(t))
        self._remember(float(dt.sum()), float(np.sum(speed * dt)), float(power @ dt), state, dt)

    def _sense(self, xy: np.ndarray, ctx) -> None:
        """The sensor footprint along the batch, from the last position the map allowed."""
        r = ctx.scenario.mission.sensor_radius_m
        seen = footprint(ctx.world, np.vstack([self.last_free_xy_m, xy]), r)
        self.covered = seen if self.covered.is_empty else self.covered.union(seen)
        self.last_free_xy_m = xy[-1]

    def _remember(self, duration_s, distance_m, measured_J, state, dt) -> None:
        """Keep the last ``window_s`` of batches: what was measured and the motion, so any
        model's prediction for the same motion can be made."""
        wind = tuple(float(np.sum(np.asarray(w) * dt))
                     for w in (state.wind_x_mps, state.wind_y_mps))
        self.window.append(Batch(duration_s, distance_m, measured_J, state, dt, wind))
        span = sum(b.duration_s for b in self.window)
        while len(self.window) > 1 and span - self.window[0].duration_s >= self.window_s:
            span -= self.window.popleft().duration_s
