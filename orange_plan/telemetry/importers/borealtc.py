"""BorealTC Husky A200 runs (``pro_NN.csv`` [+ ``imu_NN.csv``]) -> recording table.

Source: LaRocque et al., "Proprioception Is All You Need: Terrain Classification for Boreal
Forests", arXiv 2403.16877 (IROS 2024), norlab-ulaval/BorealTC, CC0 1.0.

* ``pro_NN.csv`` (about 6.5 Hz): ``time`` [s], ``curL``/``curR`` motor currents [A],
  ``velL``/``velR`` wheel speeds [m/s]. No battery voltage is logged: the Husky bus is
  nominally ``BUS_VOLTAGE_V`` = 24 V, so ``power_W = 24 x (|curL| + |curR|)`` (motor
  electrical power only: the computer and sensors are on other rails and not in this power).
  The logged currents are never negative (0 of 27,331 samples over the 44 runs): they are
  clipped at zero, so the ``abs`` changes nothing, and a motor that brakes (is back-driven)
  reads 0 A. In forward turns (both wheels forward, inner/outer speed ratio < 0.8) the inner
  wheel reads exactly 0 A in 40 % of samples (mean 1.2 A, outer 9.1 A); in SNOW/pro_26 the
  inner (left) wheel reads 0 A for 83 % of the run. Braking and any regeneration are
  therefore invisible in ``power_W``, and a forward turn costs less than a spin in place,
  where both motors drive against the scrub.
* ``v_mps = (velL + velR) / 2`` (signed; the recording checks take the magnitude).
* ``yaw_rate_radps``: IMU ``wz`` (100 Hz) averaged over one ``pro`` interval (centred
  moving average) and interpolated onto the ``pro`` stamps. Without a usable ``imu_NN.csv``
  (missing or empty, as FLOORING/imu_04.csv is): ``(velR - velL) / TRACK_WIDTH_M``
  (skid-steer kinematics; over-estimates while slipping), noted in the recording's issues.
* ``wheel_yaw_rate_radps`` (extra column) = ``(velR - velL) / TRACK_WIDTH_M`` always: on snow
  the wheels often counter-rotate while the body barely turns (IMU), and the slip power
  follows the wheels, not the body; a diagnosis can compare both.
* ``surface``: the folder name in lower case (``asphalt``, ``flooring``, ``snow``).
* No position is recorded. The raw channels are kept as extra columns.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from orange_plan.errors import RecordingError
from orange_plan.telemetry.importers._common import need_rows, onto_times

BUS_VOLTAGE_V = 24.0
"""Husky A200 nominal bus voltage (the data set's documentation; Clearpath spec sheet) [V]."""
TRACK_WIDTH_M = 0.55
"""Husky track width (the data set's documentation) [m]."""
PRO_COLUMNS = ("time", "curL", "curR", "velL", "velR")
NAME = re.compile(r"^pro_(\d+)\.csv$", re.IGNORECASE)


def is_borealtc(path: Path) -> bool:
    """A ``pro_NN.csv`` file whose header starts with BorealTC's columns."""
    if not (path.is_file() and NAME.match(path.name)):
        return False
    with open(path, encoding="utf-8", errors="replace") as fh:
        header = fh.readline().strip().split(",")
    return tuple(header[: len(PRO_COLUMNS)]) == PRO_COLUMNS


def read_borealtc(path: str | Path) -> pd.DataFrame:
    """Read one BorealTC run (the ``pro_NN.csv`` file) into recording columns (docs/formats.md).

    Raises
    ------
    RecordingError
        Not a ``pro_NN.csv`` file or missing BorealTC columns.
    """
    path = Path(path)
    match = NAME.match(path.name)
    if not match:
        raise RecordingError(f"{path}: a BorealTC run is a 'pro_NN.csv' file")
    pro = pd.read_csv(path)
    missing = [c for c in PRO_COLUMNS if c not in pro.columns]
    if missing:
        raise RecordingError(f"{path}: BorealTC column '{missing[0]}' is missing")
    need_rows(pro, "BorealTC", path)
    t_s = pd.to_numeric(pro["time"], errors="coerce").to_numpy(float)
    cur_l, cur_r = pro["curL"].to_numpy(float), pro["curR"].to_numpy(float)
    vel_l, vel_r = pro["velL"].to_numpy(float), pro["velR"].to_numpy(float)
    wheel_yaw = (vel_r - vel_l) / TRACK_WIDTH_M
    imu_path = path.with_name(f"imu_{match.group(1)}.csv")
    yaw, note = _yaw_rate(imu_path, t_s, wheel_yaw)
    frame = pd.DataFrame({
        "t_s": t_s,
        "power_W": BUS_VOLTAGE_V * (np.abs(cur_l) + np.abs(cur_r)),
        "v_mps": 0.5 * (vel_l + vel_r),
        "yaw_rate_radps": yaw,
        "surface": path.parent.name.lower(),
        "wheel_yaw_rate_radps": wheel_yaw,
        "current_left_A": cur_l, "current_right_A": cur_r,
        "wheel_left_mps": vel_l, "wheel_right_mps": vel_r,
    })
    if note:
        frame.attrs["import_notes"] = [note]  # becomes a DataIssue in recording_from_frame
    return frame


def _read_imu(imu_path: Path) -> pd.DataFrame | None:
    """The IMU's time and wz, or None when the file is missing, empty or lacks them."""
    try:
        imu = pd.read_csv(imu_path, usecols=["time", "wz"])
    except (OSError, ValueError, pd.errors.EmptyDataError):
        return None
    return imu if len(imu) >= 2 else None


def _yaw_rate(imu_path: Path, t_s: np.ndarray, wheel_yaw_radps: np.ndarray):
    """IMU yaw rate on the pro stamps, and a note when the wheels had to stand in."""
    imu = _read_imu(imu_path)
    if imu is None:
        return wheel_yaw_radps, (f"{imu_path.name} missing or empty: yaw_rate_radps from wheel "
                                 f"speeds (velR - velL) / {TRACK_WIDTH_M} m")
    imu_t = imu["time"].to_numpy(float)
    dt_imu = float(np.median(np.diff(imu_t)))
    dt_pro = float(np.median(np.diff(t_s)))
    # Average over one pro interval so a 100 Hz vibration does not alias onto 6.5 Hz.
    window = max(1, round(dt_pro / dt_imu))
    wz = imu["wz"].rolling(window, center=True, min_periods=1).mean().to_numpy(float)
    yaw = onto_times(t_s, imu_t, wz, max_gap_s=max(1.0, 3 * dt_pro))
    gaps = ~np.isfinite(yaw)
    note = (f"{int(gaps.sum())} sample(s) without IMU data: yaw_rate_radps from wheel speeds"
            if gaps.any() else "")
    return np.where(gaps, wheel_yaw_radps, yaw), note
