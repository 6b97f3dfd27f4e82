"""PX4 ULog (``.ulg``) -> recording table, with pyulog.

Reads ``battery_status`` (``voltage_v`` [V], ``current_a`` [A], discharge positive in PX4;
-1 means "unknown" and becomes a missing value) and ``vehicle_local_position`` (``x, y, z``
in NED: x north, y east, z down; ``vx, vy`` [m/s]). The recording frame is x east, y north,
z up, so ``x_m = y``, ``y_m = x``, ``z_m = -z``, ``v_mps = hypot(vx, vy)``.

Time grid: the battery samples (the measured energy is never resampled); positions and
velocities are interpolated linearly onto it, and left missing where no position sample
lies within ``MAX_GAP_S`` (the recording checks then report and drop those rows).
``t_s`` counts from the first battery sample.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from orange_plan.errors import RecordingError
from orange_plan.telemetry.importers._common import need_rows, onto_times

MAX_GAP_S = 1.0
"""Largest distance from a battery stamp to the nearest position sample [s]."""

TOPICS = ("battery_status", "vehicle_local_position")


def read_ulog(path: str | Path) -> pd.DataFrame:
    """Read a PX4 ULog into recording columns (docs/formats.md) (see the module docstring for the mapping).

    Raises
    ------
    RecordingError
        Unreadable file, or no battery_status / vehicle_local_position samples.
    """
    from pyulog import ULog

    path = Path(path)
    try:
        log = ULog(str(path), message_name_filter_list=list(TOPICS))
    except Exception as exc:  # noqa: BLE001 - pyulog raises bare exceptions on bad files
        raise RecordingError(f"{path}: not a readable PX4 ULog file ({exc})") from None
    battery = _topic(log, "battery_status", path)
    position = _topic(log, "vehicle_local_position", path)
    t0_us = float(battery["timestamp"][0])
    t_s = (battery["timestamp"].astype(float) - t0_us) / 1e6
    pos_t_s = (position["timestamp"].astype(float) - t0_us) / 1e6
    current = battery["current_a"].astype(float)
    frame = pd.DataFrame({
        "t_s": t_s,
        "voltage_V": battery["voltage_v"].astype(float),
        "current_A": np.where(current == -1.0, np.nan, current),
    })

    def at(field):
        return onto_times(t_s, pos_t_s, position[field].astype(float), MAX_GAP_S)

    frame["x_m"], frame["y_m"], frame["z_m"] = at("y"), at("x"), -at("z")
    frame["v_mps"] = np.hypot(at("vx"), at("vy"))
    if "remaining" in battery:
        frame["soc"] = battery["remaining"].astype(float)
    frame["power_W"] = frame["voltage_V"] * frame["current_A"]
    need_rows(frame, "battery_status", path)
    return frame


def _topic(log, name: str, path: Path) -> dict:
    found = [d for d in log.data_list if d.name == name]
    if not found or len(found[0].data["timestamp"]) == 0:
        raise RecordingError(f"{path}: the ULog has no '{name}' messages")
    return found[0].data
