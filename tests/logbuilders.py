"""Tiny robot logs built in the tests: PX4 ULog (written byte by byte), ROS 1 / ROS 2 bags.

Every log describes the same drive: 10 s, battery at 2 Hz (24 V, 2 A discharge, so 48 W),
odometry / position at 10 Hz moving east at 0.5 m/s (ENU) with a constant climb of 0.1 m/s.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

DURATION_S = 10.0
BATTERY_HZ = 2.0
POSITION_HZ = 10.0
VOLTAGE_V, CURRENT_A = 24.0, 2.0
SPEED_EAST_MPS, CLIMB_MPS = 0.5, 0.1
T0_NS = 1_700_000_000 * 10**9  # an epoch stamp, as real bags have


def battery_times_s() -> np.ndarray:
    return np.arange(0.0, DURATION_S + 1e-9, 1.0 / BATTERY_HZ)


def position_times_s() -> np.ndarray:
    return np.arange(0.0, DURATION_S + 1e-9, 1.0 / POSITION_HZ)


# --- ULog (https://docs.px4.io/main/en/dev_log/ulog_file_format.html) ----------------------

def _msg(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def write_ulog(path: Path, current_unknown_at: int | None = None) -> Path:
    """A minimal ULog v1: flag bits, two formats, two subscriptions, data messages (NED)."""
    out = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", 0))
    out += _msg(b"B", bytes(8) + bytes(8) + bytes(24))
    out += _msg(b"F", b"battery_status:uint64_t timestamp;float voltage_v;float current_a;"
                      b"float remaining;")
    out += _msg(b"F", b"vehicle_local_position:uint64_t timestamp;float x;float y;float z;"
                      b"float vx;float vy;")
    out += _msg(b"A", struct.pack("<BH", 0, 0) + b"battery_status")
    out += _msg(b"A", struct.pack("<BH", 0, 1) + b"vehicle_local_position")
    t_start_us = 5_000_000
    items = []
    for i, t in enumerate(battery_times_s()):
        current = -1.0 if i == current_unknown_at else CURRENT_A
        items.append((t, struct.pack("<HQfff", 0, t_start_us + int(t * 1e6), VOLTAGE_V, current,
                                     1.0 - 0.01 * t)))
    for t in position_times_s():
        # NED: north = y_enu (0), east = x_enu, down = -z_enu
        east, up = SPEED_EAST_MPS * t, CLIMB_MPS * t
        items.append((t, struct.pack("<HQfffff", 1, t_start_us + int(t * 1e6), 0.0, east, -up,
                                     0.0, SPEED_EAST_MPS)))
    for _, payload in sorted(items, key=lambda it: it[0]):
        out += _msg(b"D", payload)
    path.write_bytes(bytes(out))
    return path


# --- ROS bags ---------------------------------------------------------------------------------

def _header(typestore, ros1: bool, stamp_ns: int):
    Header = typestore.types["std_msgs/msg/Header"]
    Time = typestore.types["builtin_interfaces/msg/Time"]
    stamp = Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return Header(seq=0, stamp=stamp, frame_id="odom") if ros1 else Header(stamp=stamp,
                                                                           frame_id="odom")


def battery_msg(typestore, ros1: bool, stamp_ns: int, current_ros_A: float):
    B = typestore.types["sensor_msgs/msg/BatteryState"]
    return B(header=_header(typestore, ros1, stamp_ns), voltage=VOLTAGE_V, temperature=20.0,
             current=current_ros_A, charge=10.0, capacity=20.0, design_capacity=20.0,
             percentage=0.8, power_supply_status=2, power_supply_health=1,
             power_supply_technology=2, present=True,
             cell_voltage=np.array([4.0], dtype=np.float32),
             cell_temperature=np.array([20.0], dtype=np.float32), location="base",
             serial_number="x")


def odometry_msg(typestore, ros1: bool, stamp_ns: int, t_s: float):
    ts = typestore.types
    pose = ts["geometry_msgs/msg/Pose"](
        position=ts["geometry_msgs/msg/Point"](x=SPEED_EAST_MPS * t_s, y=0.0, z=CLIMB_MPS * t_s),
        orientation=ts["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
    vec = ts["geometry_msgs/msg/Vector3"]
    twist = ts["geometry_msgs/msg/Twist"](linear=vec(x=SPEED_EAST_MPS, y=0.0, z=CLIMB_MPS),
                                          angular=vec(x=0.0, y=0.0, z=0.05))
    return ts["nav_msgs/msg/Odometry"](
        header=_header(typestore, ros1, stamp_ns), child_frame_id="base_link",
        pose=ts["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=ts["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)))


def _messages():
    """(stamp_ns, kind, t_s) in time order."""
    items = [(T0_NS + int(t * 1e9), "battery", t) for t in battery_times_s()]
    items += [(T0_NS + int(t * 1e9), "odom", t) for t in position_times_s()]
    return sorted(items, key=lambda it: (it[0], it[1]))


def write_rosbag1(path: Path, with_battery: bool = True, nan_current_at: int | None = None) -> Path:
    """A ROS 1 bag; ``nan_current_at``: that battery message reports an unmeasured current."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    with Writer(path) as writer:
        batt = writer.add_connection("/battery", "sensor_msgs/msg/BatteryState", typestore=ts)
        odom = writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        n_battery = 0
        for stamp, kind, t in _messages():
            if kind == "battery" and with_battery:
                current = np.nan if n_battery == nan_current_at else -CURRENT_A
                n_battery += 1
                msg = battery_msg(ts, True, stamp, current)  # ROS: negative = discharging
                writer.write(batt, stamp, ts.serialize_ros1(msg, "sensor_msgs/msg/BatteryState"))
            elif kind == "odom":
                msg = odometry_msg(ts, True, stamp, t)
                writer.write(odom, stamp, ts.serialize_ros1(msg, "nav_msgs/msg/Odometry"))
    return path


def write_rosbag2(path: Path, storage: str = "sqlite3") -> Path:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        batt = writer.add_connection("/battery", "sensor_msgs/msg/BatteryState", typestore=ts)
        odom = writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        for stamp, kind, t in _messages():
            if kind == "battery":
                msg = battery_msg(ts, False, stamp, -CURRENT_A)
                writer.write(batt, stamp, ts.serialize_cdr(msg, "sensor_msgs/msg/BatteryState"))
            else:
                msg = odometry_msg(ts, False, stamp, t)
                writer.write(odom, stamp, ts.serialize_cdr(msg, "nav_msgs/msg/Odometry"))
    return path
