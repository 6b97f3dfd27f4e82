"""ROS 1 bags and ROS 2 bags (sqlite3 ``.db3`` or MCAP, directory or single file) -> recording.

Uses rosbags' AnyReader. Topics are picked by message type, not by name:

* ``sensor_msgs/msg/BatteryState``: ``voltage`` [V] and ``current`` [A]. ROS defines the
  current as negative while discharging; the recording's convention is discharge positive,
  so ``current_A = -current``. ``percentage`` (0..1) becomes ``soc`` when it is finite.
* ``nav_msgs/msg/Odometry``: ``pose.pose.position`` -> ``x_m, y_m, z_m`` (REP 103: ENU
  frame, used as the map frame); ``twist.twist.linear`` (body frame) -> ``v_mps =
  hypot(x, y)``; ``twist.twist.angular.z`` -> ``yaw_rate_radps``.

Stamps are the bag's receive times (header stamps can be zero or in simulated time).
Time grid: the battery messages; odometry is interpolated linearly onto it and left missing
where no odometry message lies within ``MAX_GAP_S``. ``t_s`` counts from the first battery
message. With several topics of one type, the one with the most messages is used.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from orange_plan.errors import RecordingError
from orange_plan.telemetry.importers._common import need_rows, onto_times

MAX_GAP_S = 1.0
"""Largest distance from a battery stamp to the nearest odometry message [s]."""

BATTERY = "sensor_msgs/msg/BatteryState"
ODOMETRY = "nav_msgs/msg/Odometry"


def read_rosbag1(path: str | Path) -> pd.DataFrame:
    """Read a ROS 1 ``.bag`` into recording columns (docs/formats.md) (module docstring: mapping and grid)."""
    return _read_bag(Path(path))


def read_rosbag2(path: str | Path) -> pd.DataFrame:
    """Read a ROS 2 bag (directory, ``.db3`` or ``.mcap``) into recording columns (docs/formats.md)."""
    return _read_bag(Path(path))


def _read_bag(path: Path) -> pd.DataFrame:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    battery, odometry = [], []
    try:
        # The default typestore serves bags without embedded definitions (older .db3).
        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            conns = {BATTERY: _busiest(reader, BATTERY), ODOMETRY: _busiest(reader, ODOMETRY)}
            if conns[BATTERY] is None:
                raise RecordingError(f"{path}: the bag has no {BATTERY} topic")
            if conns[ODOMETRY] is None:
                raise RecordingError(f"{path}: the bag has no {ODOMETRY} topic")
            wanted = list(conns.values())
            for conn, stamp_ns, raw in reader.messages(connections=wanted):
                msg = reader.deserialize(raw, conn.msgtype)
                if conn.msgtype == BATTERY:
                    battery.append(_battery_row(stamp_ns, msg))
                else:
                    odometry.append(_odometry_row(stamp_ns, msg))
    except RecordingError:
        raise
    except Exception as exc:  # noqa: BLE001 - rosbags raises many types for a bad bag
        raise RecordingError(f"{path}: not a readable ROS bag ({type(exc).__name__}: {exc})") from None
    return _merge(pd.DataFrame(battery), pd.DataFrame(odometry), path)


def _busiest(reader, msgtype: str):
    conns = [c for c in reader.connections if c.msgtype == msgtype]
    return max(conns, key=lambda c: c.msgcount) if conns else None


def _battery_row(stamp_ns: int, msg) -> dict:
    pct = float(msg.percentage)
    return {"stamp_ns": stamp_ns, "voltage_V": float(msg.voltage),
            "current_A": -float(msg.current), "soc": pct if np.isfinite(pct) else np.nan}


def _odometry_row(stamp_ns: int, msg) -> dict:
    p, lin = msg.pose.pose.position, msg.twist.twist.linear
    return {"stamp_ns": stamp_ns, "x_m": float(p.x), "y_m": float(p.y), "z_m": float(p.z),
            "v_mps": float(np.hypot(lin.x, lin.y)),
            "yaw_rate_radps": float(msg.twist.twist.angular.z)}


def _merge(battery: pd.DataFrame, odometry: pd.DataFrame, path: Path) -> pd.DataFrame:
    need_rows(battery, BATTERY, path)
    need_rows(odometry, ODOMETRY, path)
    t0_ns = int(battery["stamp_ns"].iloc[0])
    t_s = (battery["stamp_ns"].to_numpy(np.int64) - t0_ns) / 1e9
    odo_t_s = (odometry["stamp_ns"].to_numpy(np.int64) - t0_ns) / 1e9
    frame = pd.DataFrame({"t_s": t_s, "voltage_V": battery["voltage_V"].to_numpy(float),
                          "current_A": battery["current_A"].to_numpy(float)})
    frame["power_W"] = frame["voltage_V"] * frame["current_A"]
    for col in ("x_m", "y_m", "z_m", "v_mps", "yaw_rate_radps"):
        frame[col] = onto_times(t_s, odo_t_s, odometry[col].to_numpy(float), MAX_GAP_S)
    if battery["soc"].notna().any():
        frame["soc"] = battery["soc"].to_numpy(float)
    return frame
