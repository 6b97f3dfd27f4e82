"""TUM BMW i3 (60 Ah) trips (``TripAxx.csv(.gz)``) -> recording table.

Source: "Battery and heating data in real driving cycles", TUM Institute of Automotive
Technology (Steinstraeter et al.), IEEE DataPort, doi 10.21227/6jr9-5235.

The file is ``;``-separated, latin-1 encoded (degree signs), 10 Hz. Columns are matched by
their name before the unit bracket, so the garbled degree sign does not matter.

* ``t_s`` = Time [s]; ``v_mps`` = Velocity [km/h] / 3.6; ``z_m`` = Elevation [m].
* The Longitudinal Acceleration [m/s^2] sensor is kept as ``accel_sensor_mps2`` but is *not*
  the recording's ``accel_mps2``: it carries a per-trip offset of -0.06..+0.04 m/s^2 against
  the derivative of the speed (mounting tilt / gravity on slopes), and over a trip an offset
  b adds m b x distance to the inertia energy (TripA11: -0.056 m/s^2 x 17.7 km x 1.6 t =
  -0.4 kWh of 2.7 kWh) and steals the grade's role (fitted grade mass ~0). ``accel_mps2`` is
  therefore derived from ``v_mps`` (telemetry.recording: moving average, central
  differences), whose integral telescopes to the kinetic-energy change.
* The set's battery current is negative while discharging; the recording's convention is
  discharge positive, so ``current_A = -current`` and ``power_W = voltage_V x current_A``.
* ``battery_C``, ``ambient_C``; ``soc`` = SoC [%] / 100.
* ``hvac_W`` = AirCon Power [kW] x 1000: the cabin HVAC electrical power (compressor on the
  high-voltage bus; at standstill battery power = 0.41 kW + 1.1 x AirCon Power over 16 trips).
* ``heater_request_W`` = Requested Heating Power [W]: the climate control's heating demand.
  The high-voltage heater's own draw is not recorded (Heating Power CAN holds stale
  constants, 5.32 kW for a whole 30 degC trip). The request is not the draw either: its
  unexplained battery power is ~1x the request at its onset in TripA03/A13/A16, ~0.2x later
  in TripA16 and ~0 while parked in TripA15 (the heater cycles and stops once the coolant is
  warm), so the ``heater`` term fits one mean share of it.
* Extra columns kept: ``heating_W`` = Heating Power CAN [kW] x 1000, ``aircon_W`` = AirCon
  Power [kW] x 1000, ``throttle_pct``, ``motor_torque_Nm``, ``cabin_C``,
  ``accel_sensor_mps2``.
* No position is recorded.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from orange_plan.errors import RecordingError

KMH_PER_MPS = 3.6

# recording column -> (source name before the unit bracket, scale)
COLUMNS = {
    "t_s": ("Time", 1.0),
    "v_mps": ("Velocity", 1.0 / KMH_PER_MPS),
    "z_m": ("Elevation", 1.0),
    "accel_sensor_mps2": ("Longitudinal Acceleration", 1.0),
    "voltage_V": ("Battery Voltage", 1.0),
    "current_A": ("Battery Current", -1.0),
    "battery_C": ("Battery Temperature", 1.0),
    "soc": ("SoC", 0.01),
    "ambient_C": ("Ambient Temperature", 1.0),
    "heating_W": ("Heating Power CAN", 1000.0),
    "aircon_W": ("AirCon Power", 1000.0),
    "hvac_W": ("AirCon Power", 1000.0),
    "heater_request_W": ("Requested Heating Power", 1.0),
    "throttle_pct": ("Throttle", 1.0),
    "motor_torque_Nm": ("Motor Torque", 1.0),
    "cabin_C": ("Cabin Temperature Sensor", 1.0),
}
REQUIRED = ("t_s", "v_mps", "voltage_V", "current_A")


def _key(name: str) -> str:
    return name.split("[")[0].strip().lower()


def is_tum_bmw_i3(path: Path) -> bool:
    """A ``;``-separated table whose header has the set's Time and Velocity [km/h] columns."""
    if not path.is_file():
        return False
    try:
        head = pd.read_csv(path, sep=";", encoding="latin1", nrows=0).columns
    except Exception:  # noqa: BLE001 - any unreadable file is simply not this format
        return False
    names = {_key(c) for c in head}
    return "time" in names and "velocity" in names and "battery current" in names


def read_tum_bmw_i3(path: str | Path) -> pd.DataFrame:
    """Read one trip into recording columns (docs/formats.md) (see the module docstring for the mapping).

    Raises
    ------
    RecordingError
        Unreadable file or a required column (time, velocity, battery voltage or current)
        missing.
    """
    path = Path(path)
    try:
        raw = pd.read_csv(path, sep=";", encoding="latin1")
    except Exception as exc:  # noqa: BLE001 - pandas/gzip raise many types
        raise RecordingError(f"{path}: cannot read the TUM BMW i3 trip ({exc})") from None
    by_key = {_key(c): c for c in raw.columns}
    frame = pd.DataFrame(index=raw.index)
    for column, (source, scale) in COLUMNS.items():
        name = by_key.get(source.lower())
        if name is None:
            if column in REQUIRED:
                raise RecordingError(f"{path}: TUM BMW i3 column '{source}' is missing")
            continue
        frame[column] = pd.to_numeric(raw[name], errors="coerce").to_numpy(float) * scale
    frame["power_W"] = frame["voltage_V"] * frame["current_A"]
    if len(frame) and not np.isfinite(frame["t_s"]).any():
        raise RecordingError(f"{path}: the Time column holds no number")
    return frame
