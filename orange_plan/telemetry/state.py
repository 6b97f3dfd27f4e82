"""One path from a recording to the model's input: ``recording_state``.

predict (replay), calibrate, the online estimator (mission session, benchmarks) and
diagnosis all read a recording's motion through this function, so they see the same
wheels-up rows, the same yaw rate and the same operating-condition channels.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from orange_plan.errors import InputError
from orange_plan.physics.conditions import Conditions
from orange_plan.physics.state import CHANNELS, MotionState
from orange_plan.physics.wind import wind_vector_mps
from orange_plan.telemetry.derive import (
    STILL_SPEED_MPS,
    gap_free_pieces,
    position_heading_rad,
    position_noise_m,
    smooth,
    smooth_pieces,
    window_samples,
)
from orange_plan.telemetry.recording import Recording, cumulative_J

GRADE_WINDOW_M = 20.0
"""Distance window of the moving average on elevation before taking the grade [m]."""
HEADING_NOISE_PATHS = 8.0
"""The direction of travel is taken over at least this many times the positions' noise of
path (``telemetry.derive.position_noise_m``) [-]. A heading differenced over less swings
with the noise: over the 0.5 m a 1 m/s boat covers in half a second, GNSS noise of 0.3 m
puts it tens of degrees off. The drag under a wind or a water current depends on it: a
noisy heading under-reads the current's share (its cosine averages below 1), and the
residual left follows the heading over the run's legs, where slow terms of time can take it
up. A path longer than needed rounds off the turns instead (a ground robot's 5 cm of noise
needs 0.4 m: no more than the usual half-second window), so the window follows the noise
the recording shows."""
WHEELS_UP_COLUMN = "wheels_up"
"""Optional recording column: true where the robot runs with its wheels in the air."""
DERIVED_CHANNELS = {"elapsed_s": lambda recording: recording.t_s - recording.t_s[0]}
"""Channels computed from the table itself; every other declared channel is read from the
recording column of its name (a missing value or column counts as 0)."""


def recording_state(recording: Recording, world=None, sensor_rate_Hz: float = 0.0,
                    default_crr: float | None = None, grade_window_m: float | None = None,
                    yaw_rate_column: str | None = None,
                    conditions: Conditions | None = None) -> MotionState:
    """Per-sample MotionState of a recording, for ``EnergyModel.power_W`` and its Jacobian.

    Parameters
    ----------
    recording : the cleaned recording
    world : optional World: rolling coefficient and surface at (x, y), surface names
    sensor_rate_Hz : used where the recording has no ``sensor_rate_Hz`` column [Hz]
    default_crr : rolling coefficient where nothing else says [-]; default the world's
        default (map default surface, else robot.crr), else 0
    grade_window_m : distance window of the moving average on ``z_m`` [m]; None:
        ``GRADE_WINDOW_M`` (suits GPS/DEM elevation outdoors; use ~1 m on a lab ramp)
    yaw_rate_column : take the yaw rate from this column instead of ``yaw_rate_radps``
        (e.g. BorealTC's ``wheel_yaw_rate_radps``: skid-steer scrub follows the wheels)
    conditions : the mission's operating conditions; when given, its sensor rate replaces
        ``sensor_rate_Hz``, its wind is the wind of a recording without wind columns, and
        its ``channels`` (the ambient temperature) are the value of a channel whose column
        the recording lacks (else 0)

    Returns
    -------
    MotionState
        Arrays of one value per sample.

    Raises
    ------
    InputError
        ``yaw_rate_column`` is not in the recording.

    Notes
    -----
    * Grade: ``z_m`` resampled on distance travelled (trapezoid of ``v_mps``), moving
      average over ``grade_window_m``, differentiated to a slope ``s = dz / ds``; ``sin_t = s``
      (clipped to [-1, 1]), ``cos_t = sqrt(1 - s^2)``. So the grade's power ``m g sin_t v``
      is the rate of climb's ``m g dz/dt``, whether ``v_mps`` runs along the path (wheels, a
      speedometer, the simulator) or is horizontal (positions, a GNSS ground speed). No
      ``z_m``: flat.
    * Direction: heading of positions (held while standing); no positions: (1, 0).
    * Wind: ``wind_mps``/``wind_from_deg`` columns (meteorological: docs/guide/range.md), else the
      conditions' wind (a session's measured wind: ``conditions.with_wind``), else none.
    * Rolling coefficient: the world at (x, y) when both exist; else the ``surface`` column
      looked up among the map's surfaces (unknown labels: default); else the default.
    * Channels (``physics.state.CHANNELS``, e.g. cabin HVAC power, the requested heating
      power): the column of the channel's name, a missing value counting as 0; elapsed time
      (warm-up drift): ``t_s - t_s[0]``.
    * Wheels up (``wheels_up`` column true): no speed over ground, grade, acceleration or
      turning on those rows (bench tests of the drivetrain draw only its idle power).
    """
    if conditions is not None:
        sensor_rate_Hz = conditions.sensor_rate_Hz
    frame = recording.frame
    n = len(frame)
    t = recording.t_s
    speed = np.abs(frame["v_mps"].to_numpy(float))
    pieces = gap_free_pieces(t, recording.gap_threshold_s)
    cos_t, sin_t = _grade(recording, speed, GRADE_WINDOW_M if grade_window_m is None
                          else grade_window_m)
    dir_x, dir_y = _direction(frame, t, pieces, speed)
    wind_x, wind_y = _wind(frame, conditions, n)
    crr, code = _rolling(frame, world, default_crr, n)
    if "sensor_rate_Hz" in frame.columns:
        rate = frame["sensor_rate_Hz"].to_numpy(float)
    else:
        rate = np.full(n, float(sensor_rate_Hz))
    defaults = conditions.channels if conditions is not None else {}
    channels = {name: DERIVED_CHANNELS[name](recording) if name in DERIVED_CHANNELS
                else _column_or_default(frame, name, defaults.get(name, 0.0))
                for name in CHANNELS}
    state = MotionState(
        speed_mps=speed, cos_t=cos_t, sin_t=sin_t, dir_x=dir_x, dir_y=dir_y,
        wind_x_mps=wind_x, wind_y_mps=wind_y, crr=crr,
        accel_mps2=frame["accel_mps2"].to_numpy(float),
        yaw_rate_radps=_yaw_rate(recording, yaw_rate_column),
        sensor_rate_Hz=rate, surface_code=code, channels=channels,
    )
    wheels = wheels_up(recording)
    return _no_traction(state, wheels) if wheels.any() else state


def _yaw_rate(recording: Recording, column: str | None) -> np.ndarray:
    if column is None:
        return recording.frame["yaw_rate_radps"].to_numpy(float)
    if column not in recording.frame.columns:
        raise InputError(f"{recording.source}: no column '{column}' for the yaw rate")
    return recording.frame[column].to_numpy(float)


def wheels_up(recording: Recording) -> np.ndarray:
    """True on rows whose ``wheels_up`` column says so (1, true, yes); all False without it."""
    if WHEELS_UP_COLUMN not in recording.frame.columns:
        return np.zeros(len(recording.frame), bool)
    col = recording.frame[WHEELS_UP_COLUMN]
    if col.dtype == object:
        return col.astype(str).str.strip().str.lower().isin(["1", "true", "yes"]).to_numpy()
    return col.fillna(0).to_numpy(float) != 0


def _no_traction(state: MotionState, mask: np.ndarray) -> MotionState:
    """Wheels in the air: no speed over ground, grade, acceleration or turning."""
    zero = {"speed_mps": 0.0, "sin_t": 0.0, "cos_t": 1.0, "accel_mps2": 0.0,
            "yaw_rate_radps": 0.0}
    changes = {}
    for name, value in zero.items():
        arr = np.array(np.broadcast_to(np.asarray(getattr(state, name), float), mask.shape))
        arr[mask] = value
        changes[name] = arr
    return state.with_(**changes)


def _column_or_default(frame: pd.DataFrame, column: str, default: float) -> np.ndarray:
    """A column as floats with missing values as ``default``, or ``default`` throughout when
    the column is absent."""
    if column not in frame.columns:
        return np.full(len(frame), float(default))
    return frame[column].fillna(default).to_numpy(float)


def distance_along_m(recording: Recording, speed_mps=None) -> np.ndarray:
    """Cumulative distance travelled at each sample (trapezoid of speed, gaps skipped) [m]."""
    speed = recording.frame["v_mps"].to_numpy(float) if speed_mps is None else speed_mps
    return cumulative_J(recording, np.abs(speed))


def _grade(recording: Recording, speed: np.ndarray, window_m: float):
    """(cos_t, sin_t) of the recording's grade (``recording_state``'s notes): ``sin_t`` is the
    slope of ``z_m`` against the distance the speed integrates to, so that ``sin_t v`` is
    ``dz/dt``. Read as a tangent (``s / sqrt(1 + s^2)``), the slope of a speed along the path
    came out ``1/sqrt(1 + s^2)`` short (3 % at a 25 % grade): the fitted grade coefficient
    rose to make up the average and left a residual cubic in the grade, which an in-battery
    loss ``k P^2`` took up."""
    n = len(speed)
    if not recording.has("z_m"):
        return np.ones(n), np.zeros(n)
    s = distance_along_m(recording, speed)
    z = recording.frame["z_m"].to_numpy(float)
    if s[-1] <= 0:
        return np.ones(n), np.zeros(n)
    step_m = max(s[-1] / 200_000.0, min(0.5, window_m / 10.0))
    grid = np.arange(0.0, s[-1] + step_m, step_m)
    # Standing still gives many z at one distance; np.interp takes them in order, fine for
    # a moving average over metres.
    z_grid = np.interp(grid, s, z)
    window = max(3, round(window_m / step_m))
    z_smooth = smooth(z_grid, window + 1 - window % 2)
    slope = np.interp(s, grid, np.gradient(z_smooth, step_m))
    sin_t = np.clip(slope, -1.0, 1.0)
    return np.sqrt(1.0 - sin_t**2), sin_t


def _direction(frame: pd.DataFrame, t, pieces, speed):
    """(dir_x, dir_y): the heading of the positions, smoothed over at least
    ``HEADING_NOISE_PATHS`` times their noise of path at the median moving speed."""
    if "x_m" in frame.columns and "y_m" in frame.columns:
        x, y = frame["x_m"].to_numpy(float), frame["y_m"].to_numpy(float)
        window = _heading_window(t, speed, HEADING_NOISE_PATHS * position_noise_m(x, y, pieces))
        if window > window_samples(t):
            x, y = smooth_pieces(x, window, pieces), smooth_pieces(y, window, pieces)
        heading = position_heading_rad(x, y, t, pieces, speed)
        return np.cos(heading), np.sin(heading)
    n = len(frame)
    return np.ones(n), np.zeros(n)


def _heading_window(t, speed, path_m: float) -> int:
    """Samples (odd) that cover ``path_m`` of path at the median moving speed, at most a
    quarter of the recording; 1 at rest or for no path."""
    moving = np.abs(np.asarray(speed, float))
    moving = moving[moving > STILL_SPEED_MPS]
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    if not moving.size or dt <= 0 or not path_m > 0:
        return 1
    n = round(path_m / (float(np.median(moving)) * dt))
    return min(max(n, 1), max(1, len(t) // 4)) | 1


def _wind(frame: pd.DataFrame, conditions: Conditions | None, n: int):
    if "wind_mps" in frame.columns and "wind_from_deg" in frame.columns:
        return wind_vector_mps(frame["wind_mps"].to_numpy(float),
                               frame["wind_from_deg"].to_numpy(float))
    if conditions is not None:
        wx, wy = conditions.wind_xy_mps
        return np.full(n, float(wx)), np.full(n, float(wy))
    return np.zeros(n), np.zeros(n)


def _rolling(frame: pd.DataFrame, world, default_crr, n: int):
    if default_crr is None:
        default_crr = world.default_crr if world is not None else 0.0
    crr = np.full(n, float(default_crr))
    code = np.full(n, -1, dtype=int)
    if world is None:
        return crr, code
    if "x_m" in frame.columns and "y_m" in frame.columns:
        x, y = frame["x_m"].to_numpy(float), frame["y_m"].to_numpy(float)
        code = world.surface_code_at(x, y)
        crr = np.where(code >= 0, world.crr_at(x, y), float(default_crr))
        return crr, code
    if "surface" in frame.columns:
        names = world.map.surface_names
        crr_by_name = {s.name: s.crr for s in world.map.surfaces}  # last feature wins
        labels = frame["surface"].astype(str).str.strip().to_numpy()
        for name in names:
            hit = np.char.lower(labels.astype(str)) == name.lower()
            crr[hit] = crr_by_name[name]
            code[hit] = names.index(name)
        default_name = getattr(world, "default_surface_name", None)
        if default_name:
            hit = (np.char.lower(labels.astype(str)) == default_name.lower()) & (code < 0)
            crr[hit] = float(default_crr)
    return crr, code
