"""WADL DJI Matrice 100 survey flights (``<id>.csv`` + route, waypoint events, metadata)
-> recording table.

Source: K. Shah, G. Ballard, A. Schmidt, M. Schwager, "Multidrone aerial surveys of penguin
colonies in Antarctica", Science Robotics 5, eabc3000 (2020); ground-station logs of the
k2shah/wadl repository (GPL-3.0: read the files where they are, never ship them).

A flight is four sibling files: ``<id>.csv`` (one row per battery reading, about every 10 s,
logged when the integer state of charge changes), ``<id>.route.csv`` (the uploaded waypoint
mission), ``<id>.wp_events.csv`` (when each waypoint was reached) and ``<id>.json``
(metadata: duration, landing point, fly mode, recorded energy, speed anomaly...).

The recording is put on a 1 s grid from take-off (0 s) to touch-down (``duration_s``):

* Positions (``x_m`` east, ``y_m`` north, ``z_m`` up, from the take-off point) are
  **reconstructed, not measured**: linear in time between the knots the set gives (the
  take-off point at 0 s, each battery reading's position, each waypoint-reached event, the
  landing point on the ground at touch-down). No wind is logged.
* ``v_mps`` is the speed along the 3D path (the drone's climb and descent are part of its
  motion: with it, the grade of the path times the speed is the vertical speed, so the
  model's grade term charges the weight times the climb rate).
* ``voltage_V``, ``current_A``, ``soc``, ``battery_C``: linear between readings, held before
  the first and after the last (the first airborne reading comes 5-20 s after take-off; the
  current is smoothed on board, transients under about 10 s are not visible anyway). A
  ``soc`` of a glitch reading is left out. ``power_W`` = voltage x current.
* ``yaw_rate_radps``: rate of the heading of the horizontal track (held while the drone moves
  less than ``STILL_MPS`` horizontally: on a vertical take-off or landing the heading of
  centimetre jitter means nothing).
* Extra columns: ``mode`` (DJI flight mode of the nearest earlier reading).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from orange_plan.errors import RecordingError
from orange_plan.telemetry.derive import position_yaw_rate_radps

GRID_S = 1.0
"""Time step of the recording grid [s]."""
BATTERY_COLUMNS = ("t_s", "voltage_V", "current_A", "power_W", "soc", "battery_C", "x_m",
                   "y_m", "z_m", "s_m", "mode")
ROUTE_COLUMNS = ("wp", "x_m", "y_m", "z_m", "speed_to_next_mps", "stay_s", "corner_radius_m")
SUFFIX = ".csv"
STILL_MPS = 0.5
"""Horizontal speed below which the track's heading is held [m/s]."""


def flight_files(path: str | Path) -> dict[str, Path]:
    """The four files of the flight whose battery table is ``path`` (``<id>.csv``)."""
    path = Path(path)
    stem = path.name[: -len(SUFFIX)] if path.name.endswith(SUFFIX) else path.stem
    folder = path.parent
    return {"battery": path, "route": folder / f"{stem}.route.csv",
            "events": folder / f"{stem}.wp_events.csv", "meta": folder / f"{stem}.json"}


def is_wadl(path: Path) -> bool:
    """A battery table with the set's header next to its ``.json`` and ``.route.csv``."""
    if not (path.is_file() and path.name.endswith(SUFFIX)) or path.name.endswith(".route.csv"):
        return False
    files = flight_files(path)
    if not (files["meta"].is_file() and files["route"].is_file()):
        return False
    with open(path, encoding="utf-8", errors="replace") as fh:
        header = fh.readline().strip().split(",")
    return tuple(header[: len(BATTERY_COLUMNS)]) == BATTERY_COLUMNS


def _read_csv(path: Path, what: str, columns) -> pd.DataFrame:
    if not path.is_file():
        raise RecordingError(f"{path}: the flight's {what} is missing")
    try:
        table = pd.read_csv(path)
    except Exception as exc:  # noqa: BLE001 - pandas raises many types
        raise RecordingError(f"{path}: cannot read the {what} ({exc})") from None
    missing = [c for c in columns if c not in table.columns]
    if missing:
        raise RecordingError(f"{path}: {what} column(s) {', '.join(missing)} missing")
    return table


def read_wadl_meta(path: str | Path) -> dict:
    """The flight's metadata (``<id>.json``) as a dict.

    Raises
    ------
    RecordingError
        Missing or unreadable, or without ``duration_s``.
    """
    meta_path = flight_files(path)["meta"]
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise RecordingError(f"{meta_path}: cannot read the flight metadata ({exc})") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("duration_s"), int | float):
        raise RecordingError(f"{meta_path}: no duration_s in the flight metadata")
    return meta


def read_wadl_route(path: str | Path) -> pd.DataFrame:
    """The uploaded waypoint mission (``<id>.route.csv``), one row per waypoint, in order."""
    route = _read_csv(flight_files(path)["route"], "route", ROUTE_COLUMNS)
    return route.sort_values("wp", kind="stable").reset_index(drop=True)


def _position_knots(battery: pd.DataFrame, events: pd.DataFrame, meta: dict) -> pd.DataFrame:
    """Times and positions the set gives: take-off, readings, waypoint events, touch-down."""
    end_s = float(meta["duration_s"])
    landing = (float(meta.get("landing_x_m") or 0.0), float(meta.get("landing_y_m") or 0.0))
    pieces = [pd.DataFrame({"t_s": [0.0], "x_m": [0.0], "y_m": [0.0], "z_m": [0.0]}),
              battery[["t_s", "x_m", "y_m", "z_m"]], events[["t_s", "x_m", "y_m", "z_m"]],
              pd.DataFrame({"t_s": [end_s], "x_m": [landing[0]], "y_m": [landing[1]],
                            "z_m": [0.0]})]
    knots = pd.concat(pieces, ignore_index=True).apply(pd.to_numeric, errors="coerce").dropna()
    knots = knots[(knots["t_s"] >= 0.0) & (knots["t_s"] <= end_s)]
    return knots.sort_values("t_s", kind="stable").drop_duplicates("t_s")


def _path_speed(t: np.ndarray, knots: pd.DataFrame) -> np.ndarray:
    """Speed along the 3D polyline through the knots, constant between knots [m/s]."""
    kt = knots["t_s"].to_numpy(float)
    step = np.sqrt(sum(np.diff(knots[c].to_numpy(float)) ** 2 for c in ("x_m", "y_m", "z_m")))
    dt = np.diff(kt)
    speed = np.divide(step, dt, out=np.zeros_like(step), where=dt > 0)
    index = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, max(speed.size - 1, 0))
    return speed[index] if speed.size else np.zeros_like(t)


def read_wadl(path: str | Path) -> pd.DataFrame:
    """Read one flight (its ``<id>.csv``; the sibling files are found by name) into the recording
    columns of docs/formats.md on a 1 s grid (see the module docstring).

    Raises
    ------
    RecordingError
        A sibling file missing or unreadable, a required column missing, or no battery
        reading.
    """
    files = flight_files(path)
    meta = read_wadl_meta(path)
    battery = _read_csv(files["battery"], "battery table", BATTERY_COLUMNS)
    events = _read_csv(files["events"], "waypoint events", ("t_s", "x_m", "y_m", "z_m"))
    readings = battery.dropna(subset=["t_s", "voltage_V", "current_A"])
    if readings.empty:
        raise RecordingError(f"{files['battery']}: no battery reading")
    end_s = float(meta["duration_s"])
    t = np.append(np.arange(0.0, end_s, GRID_S), end_s)
    knots = _position_knots(readings, events, meta)
    frame = pd.DataFrame({"t_s": t})
    for column in ("x_m", "y_m", "z_m"):
        frame[column] = np.interp(t, knots["t_s"], knots[column])
    frame["v_mps"] = _path_speed(t, knots)
    # the positions are already piecewise linear (interpolated knots): no smoothing
    frame["yaw_rate_radps"] = position_yaw_rate_radps(frame["x_m"].to_numpy(),
                                                      frame["y_m"].to_numpy(), t,
                                                      still_mps=STILL_MPS, window=1)
    rt = readings["t_s"].to_numpy(float)
    for column in ("voltage_V", "current_A", "battery_C"):
        frame[column] = np.interp(t, rt, readings[column].to_numpy(float))
    soc = readings.dropna(subset=["soc"])
    if "soc_glitch" in readings.columns:
        soc = soc[~soc["soc_glitch"].astype(str).str.lower().eq("true")]
    if len(soc):
        frame["soc"] = np.interp(t, soc["t_s"].to_numpy(float), soc["soc"].to_numpy(float))
    frame["power_W"] = frame["voltage_V"] * frame["current_A"]
    nearest = np.clip(np.searchsorted(rt, t, side="right") - 1, 0, rt.size - 1)
    frame["mode"] = readings["mode"].astype(str).to_numpy()[nearest]
    frame.attrs["import_notes"] = [
        "positions reconstructed from the planned waypoints and the waypoint-reached times "
        "(not measured); battery readings (about every 10 s) interpolated onto a 1 s grid"]
    return frame
