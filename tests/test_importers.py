"""Importers: tiny logs built here (ULog, ROS 1, ROS 2 sqlite3 and MCAP) and a few real runs."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from logbuilders import (
    CLIMB_MPS,
    CURRENT_A,
    DURATION_S,
    SPEED_EAST_MPS,
    VOLTAGE_V,
    write_rosbag1,
    write_rosbag2,
    write_ulog,
)

from orange_plan.errors import RecordingError
from orange_plan.telemetry.importers import FORMATS, guess_format, read_log
from orange_plan.telemetry.recording import recording_from_frame
from orange_plan.telemetry.state import recording_state

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def needs_data(sub: str) -> Path:
    path = DATA / sub
    if not path.exists():
        pytest.skip(f"real data not found at ../shared/data/{sub}")
    return path


def check_drive(frame: pd.DataFrame, n_battery: int = 21):
    """The logbuilders drive: east at 0.5 m/s, climbing 0.1 m/s, 48 W discharge."""
    assert len(frame) == n_battery
    assert np.allclose(frame["t_s"], np.linspace(0.0, DURATION_S, n_battery))
    assert np.allclose(frame["power_W"], VOLTAGE_V * CURRENT_A)
    assert np.allclose(frame["x_m"], SPEED_EAST_MPS * frame["t_s"], atol=1e-5)
    assert np.allclose(frame["y_m"], 0.0, atol=1e-6)
    assert np.allclose(frame["z_m"], CLIMB_MPS * frame["t_s"], atol=1e-5)
    assert np.allclose(frame["v_mps"], SPEED_EAST_MPS)
    rec = recording_from_frame(frame)
    assert rec.energy_J == pytest.approx(VOLTAGE_V * CURRENT_A * DURATION_S)
    state = recording_state(rec)
    slope = CLIMB_MPS / SPEED_EAST_MPS
    # the slope against the distance the (horizontal) speed integrates to: sin_t v = dz/dt
    assert np.allclose(state.sin_t, slope, atol=1e-3)
    assert np.allclose(state.dir_x, 1.0)


# --- PX4 ULog ------------------------------------------------------------------------------


def test_ulog_ned_becomes_enu(tmp_path):
    path = write_ulog(tmp_path / "drive.ulg")
    assert guess_format(path) == "ulog"
    frame, fmt = read_log(path)
    assert fmt == "ulog"
    check_drive(frame)
    assert frame["soc"].iloc[0] == pytest.approx(1.0)


def test_ulog_unknown_current_becomes_a_dropped_row(tmp_path):
    frame, _ = read_log(write_ulog(tmp_path / "drive.ulg", current_unknown_at=3))
    rec = recording_from_frame(frame)
    issue = next(i for i in rec.issues if i.kind == "missing_value")
    assert (issue.count, issue.first_row) == (1, 3)


def test_ulog_garbage_is_refused(tmp_path):
    path = tmp_path / "bad.ulg"
    path.write_bytes(b"ULog\x01\x12\x35\x01" + b"\xff" * 40)
    with pytest.raises(RecordingError, match=r"bad\.ulg"):
        read_log(path, "ulog")


# --- ROS bags ----------------------------------------------------------------------------------


def test_rosbag1_battery_sign_flipped_and_odometry_merged(tmp_path):
    path = write_rosbag1(tmp_path / "drive.bag")
    assert guess_format(path) == "rosbag1"
    frame, _ = read_log(path)
    check_drive(frame)
    assert np.all(frame["current_A"] > 0)  # ROS discharge is negative: flipped
    assert np.allclose(frame["yaw_rate_radps"], 0.05)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_rosbag2_directory_and_single_file(tmp_path, storage):
    folder = write_rosbag2(tmp_path / "bag", storage)
    assert guess_format(folder) == "rosbag2"
    check_drive(read_log(folder)[0])
    single = next(p for p in folder.iterdir() if p.suffix in (".db3", ".mcap"))
    assert guess_format(single) == "rosbag2"
    check_drive(read_log(single, "rosbag2")[0])


def test_unmeasured_ros_current_drops_the_row(tmp_path):
    frame, _ = read_log(write_rosbag1(tmp_path / "drive.bag", nan_current_at=4))
    rec = recording_from_frame(frame)
    issue = next(i for i in rec.issues if i.kind == "missing_value")
    assert (issue.count, issue.first_row) == (1, 4)
    assert "current_A" in issue.rule or "power_W" in issue.rule


def test_bag_without_battery_is_refused(tmp_path):
    path = write_rosbag1(tmp_path / "drive.bag", with_battery=False)
    with pytest.raises(RecordingError, match="BatteryState"):
        read_log(path)


# --- format guessing ----------------------------------------------------------------------------


def test_unknown_format_lists_the_allowed_ones(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("hello")
    with pytest.raises(RecordingError, match="one of ulog, rosbag1, rosbag2, borealtc, tum_bmw_i3, wadl"):
        guess_format(path)
    with pytest.raises(RecordingError, match="unknown format 'px5'; allowed: ulog"):
        read_log(path, "px5")
    with pytest.raises(RecordingError, match=r"no metadata\.yaml"):
        guess_format(tmp_path)
    assert set(FORMATS) == {"ulog", "rosbag1", "rosbag2", "borealtc", "tum_bmw_i3", "wadl"}


# --- the data sets' own layouts (synthetic copies, then a few real runs) -------------------------


def write_borealtc(folder: Path, with_imu: bool = True) -> Path:
    folder.mkdir(parents=True)
    t = np.arange(0, 20) / 6.5
    pd.DataFrame({"time": t, "curL": 2.0, "curR": -3.0, "velL": 0.4, "velR": 0.6}).to_csv(
        folder / "pro_07.csv", index=False)
    if with_imu:
        ti = np.arange(0, 320) / 100.0
        pd.DataFrame({"time": ti, "wx": 0.0, "wy": 0.0, "wz": 0.2, "ax": 0.0, "ay": 0.0,
                      "az": 9.81}).to_csv(folder / "imu_07.csv", index=False)
    return folder / "pro_07.csv"


@pytest.mark.parametrize("with_imu, yaw", [(True, 0.2), (False, 0.2 / 0.55)])
def test_borealtc_layout(tmp_path, with_imu, yaw):
    path = write_borealtc(tmp_path / "SNOW", with_imu)
    assert guess_format(path) == "borealtc"
    frame, _ = read_log(path)
    assert np.allclose(frame["power_W"], 24.0 * 5.0)
    assert np.allclose(frame["v_mps"], 0.5)
    assert np.allclose(frame["yaw_rate_radps"], yaw)
    assert np.allclose(frame["wheel_yaw_rate_radps"], 0.2 / 0.55)
    assert set(frame["surface"]) == {"snow"}
    fallback = [i for i in recording_from_frame(frame).issues if i.kind == "import"]
    assert len(fallback) == (0 if with_imu else 1)


def test_borealtc_empty_imu_file_falls_back_to_wheels_and_says_so(tmp_path):
    path = write_borealtc(tmp_path / "FLOORING", with_imu=False)
    (tmp_path / "FLOORING" / "imu_07.csv").write_text("")  # as FLOORING/imu_04.csv is
    rec = recording_from_frame(read_log(path)[0])
    note = next(i for i in rec.issues if i.kind == "import")
    assert "imu_07.csv missing or empty" in note.rule
    assert np.allclose(rec.frame["yaw_rate_radps"], 0.2 / 0.55)


def test_tum_bmw_i3_layout(tmp_path):
    header = ("Time [s];Velocity [km/h];Elevation [m];Longitudinal Acceleration [m/s^2];"
              "Battery Voltage [V];Battery Current [A];Battery Temperature [°C];SoC [%];"
              "Heating Power CAN [kW];AirCon Power [kW];Ambient Temperature [°C]\n")
    rows = "".join(f"{t / 10};36;500;0.1;380;-10;21;80;0;0.4;25\n" for t in range(30))
    path = tmp_path / "TripA99.csv.gz"
    with gzip.open(path, "wb") as fh:
        fh.write((header + rows).encode("latin1"))
    assert guess_format(path) == "tum_bmw_i3"
    frame, _ = read_log(path)
    assert np.allclose(frame["v_mps"], 10.0)
    assert np.allclose(frame["power_W"], 3800.0)  # negative current = discharge
    assert np.allclose(frame["soc"], 0.8)
    assert np.allclose(frame["aircon_W"], 400.0)
    assert np.allclose(frame["battery_C"], 21.0) and np.allclose(frame["ambient_C"], 25.0)


def test_tum_bmw_i3_without_current_is_refused(tmp_path):
    path = tmp_path / "TripA98.csv"
    path.write_text("Time [s];Velocity [km/h];Battery Voltage [V]\n0;0;380\n0.1;0;380\n")
    with pytest.raises(RecordingError, match="'Battery Current' is missing"):
        read_log(path, "tum_bmw_i3")


@pytest.mark.parametrize("run", ["ASPHALT/pro_01.csv", "FLOORING/pro_03.csv", "SNOW/pro_06.csv"])
def test_real_borealtc_runs(run):
    path = needs_data("borealtc") / run
    frame, fmt = read_log(path)
    assert fmt == "borealtc"
    rec = recording_from_frame(frame, str(path))
    assert 30.0 < rec.duration_s < 1000.0
    assert 50.0 < rec.energy_J / rec.duration_s < 1000.0   # a Husky draws tens to hundreds of W
    assert rec.frame["v_mps"].max() <= 1.2                  # top speed about 1 m/s
    assert rec.frame["surface"].iloc[0] == run.split("/")[0].lower()


def test_real_bmw_trip():
    path = needs_data("tum_bmw_i3") / "TripA01.csv.gz"
    frame, fmt = read_log(path)
    assert fmt == "tum_bmw_i3"
    rec = recording_from_frame(frame, str(path))
    wh_per_km = rec.energy_J / 3600 / (rec.distance_m / 1000)
    assert 100.0 < wh_per_km < 250.0                         # an i3 uses ~130-200 Wh/km
    assert rec.frame["v_mps"].max() < 45.0


def test_tum_bmw_i3_hvac_and_acceleration_from_speed(tmp_path):
    # speed 0 -> 36 km/h in 2 s (5 m/s^2); the acceleration sensor reads an offset 0.3 m/s^2
    header = ("Time [s];Velocity [km/h];Longitudinal Acceleration [m/s^2];Battery Voltage [V];"
              "Battery Current [A];AirCon Power [kW];Requested Heating Power [W]\n")
    rows = "".join(f"{t / 10};{min(t, 20) * 1.8};0.3;380;-10;0.6;{1000 * (t > 30)}\n"
                   for t in range(60))
    path = tmp_path / "TripA97.csv"
    path.write_text(header + rows, encoding="latin1")
    frame, _ = read_log(path, "tum_bmw_i3")
    assert "accel_mps2" not in frame.columns               # the offset sensor is not used ...
    assert np.allclose(frame["accel_sensor_mps2"], 0.3)     # ... but kept
    assert np.allclose(frame["hvac_W"], 600.0)              # AirCon Power [kW] -> W
    rec = recording_from_frame(frame)
    accel = rec.frame["accel_mps2"].to_numpy()
    assert accel[8] == pytest.approx(5.0) and accel[40] == pytest.approx(0.0)  # from v_mps
    state = recording_state(rec)
    assert np.allclose(state.channel("hvac_W"), 600.0)
    heater, elapsed = state.channel("heater_request_W"), state.channel("elapsed_s")
    assert heater[30] == 0.0 and heater[31] == 1000.0  # [W]
    assert elapsed[0] == 0.0 and elapsed[-1] == pytest.approx(5.9)
