"""The watch's telemetry intake: MAVLink messages from a vehicle become ``MissionSession``
samples.

A vehicle streams its position (``GLOBAL_POSITION_INT``, or ``LOCAL_POSITION_NED`` from
``HOME_POSITION``), its battery (``BATTERY_STATUS`` / ``SYS_STATUS``: voltage, current,
remaining) and the wind (``WIND`` from ArduPilot, ``WIND_COV`` from PX4). A radio link drops,
repeats and reorders messages, an autopilot may reboot in flight, and a battery monitor may
not know a field: each is said, none stops the intake.

``TelemetryReader`` turns messages into session samples (``t_s``, ``x_m``, ``y_m``,
``voltage_V``, ``current_A``, ``soc``, ``wind_mps``, ``wind_from_deg``): positions through
the map's ``origin`` (``export.autopilot.latlon_to_xy``); mission time from the vehicle's
time since boot, the first position heard being ``FIRST_SAMPLE_S``; a position not newer
than the last one is a duplicate or out of order and is dropped (counted and said); a time
since boot that falls back by more than ``REBOOT_BACKSTEP_S`` is a reboot: mission time goes
on from where it was. Battery fields marked unknown (``UINT16_MAX`` voltage, ``-1`` current
or remaining) keep the last known value; until voltage and current are both known no
sample is made.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from orange_plan.export.autopilot import latlon_to_xy
from orange_plan.physics.wind import wind_speed_and_from
from orange_plan.service.mavlink_link import INT_UNKNOWN, UINT16_UNKNOWN

FIRST_SAMPLE_S = 0.1
"""Mission time of the first position heard [s] (a session starts at 0 at home)."""
REBOOT_BACKSTEP_S = 2.0
"""A time since boot that falls back by more than this is a reboot, not a late message [s]."""
GCS_TYPE, INVALID_AUTOPILOT, ONBOARD_CONTROLLER = 6, 8, 18
"""A HEARTBEAT from a ground station (MAV_TYPE_GCS) or without autopilot is not the vehicle's."""


@dataclass
class _Battery:
    voltage_V: float | None = None
    current_A: float | None = None
    soc: float | None = None


class TelemetryReader:
    """Vehicle messages -> session samples, and what is wrong with the link (module
    docstring). ``say(kind, text)`` is told each fault once per ``repeat_s`` of wall time."""

    def __init__(self, origin, home_xy_m, say, clock=time.monotonic, repeat_s: float = 10.0):
        self.origin, self.home_xy_m, self.say, self.clock = origin, home_xy_m, say, clock
        self.repeat_s = repeat_s
        self.battery = _Battery()
        self.wind: tuple[float, float] | None = None
        self.vehicle: tuple[int, int] | None = None
        self.home_ned: tuple[float, float] | None = None  # HOME_POSITION x (north), y (east)
        self.samples: list[dict] = []
        self.arrived: list[float] = []  # wall time each sample arrived
        self.dropped = 0
        self.reboots = 0
        self._boot_last: float | None = None
        self._boot_first: float | None = None
        self._offset_s = 0.0
        self._t_last = 0.0
        self._global_seen = False
        self._said: dict[str, float] = {}

    @property
    def boot_last_s(self) -> float | None:
        """The vehicle's time since boot of the newest sample taken [s]."""
        return self._boot_last

    def tell(self, kind: str, text: str) -> None:
        """Say a fault, at most once per ``repeat_s`` for each kind."""
        now = self.clock()
        if now - self._said.get(kind, -math.inf) >= self.repeat_s:
            self._said[kind] = now
            self.say(kind, text)

    def take(self, msg) -> None:
        """One message from the link (any other type is ignored)."""
        handler = getattr(self, f"_on_{msg.get_type().lower()}", None)
        if handler is not None:
            handler(msg)

    # --- vehicle and time ------------------------------------------------------------
    def _on_heartbeat(self, msg) -> None:
        if msg.type == GCS_TYPE or msg.autopilot == INVALID_AUTOPILOT:
            return
        who = (msg.get_srcSystem(), msg.get_srcComponent())
        if self.vehicle is None:
            self.say("vehicle", f"vehicle {who[0]}/{who[1]} heard")
        self.vehicle = who

    def _mission_time(self, time_boot_ms: int) -> float | None:
        """Mission time of a message stamped ``time_boot_ms``; None for a duplicate or a
        message older than the last one taken."""
        boot = time_boot_ms / 1000.0
        if self._boot_first is None:
            self._boot_first = self._boot_last = boot
            return FIRST_SAMPLE_S
        if boot < self._boot_last - REBOOT_BACKSTEP_S:
            self.reboots += 1
            self.say("reboot", f"the vehicle rebooted (time since boot fell from "
                               f"{self._boot_last:.1f} s to {boot:.1f} s); mission time goes on")
            # mission time continues one nominal step after the last sample
            self._offset_s = self._t_last + FIRST_SAMPLE_S - (boot - self._boot_first)
            self._boot_last = boot
            return self._t_last + FIRST_SAMPLE_S
        if boot <= self._boot_last:
            self.dropped += 1
            self.tell("out_of_order", f"{self.dropped} duplicate or out-of-order position "
                                      "message(s) dropped so far")
            return None
        self._boot_last = boot
        return boot - self._boot_first + FIRST_SAMPLE_S + self._offset_s

    # --- position ----------------------------------------------------------------------
    def _on_global_position_int(self, msg) -> None:
        self._global_seen = True
        # placed on the map per batch (``pop``): the conversion is vectorised
        self._sample(msg.time_boot_ms, msg.lat / 1e7, msg.lon / 1e7, geodetic=True)

    def _on_local_position_ned(self, msg) -> None:
        if self._global_seen:  # the global position is the one placed by the origin
            return
        if self.home_ned is None:
            self.tell("no_home", "LOCAL_POSITION_NED without HOME_POSITION: cannot place it "
                                 "on the map yet")
            return
        north, east = msg.x - self.home_ned[0], msg.y - self.home_ned[1]
        self._sample(msg.time_boot_ms, self.home_xy_m[0] + east, self.home_xy_m[1] + north)

    def _on_home_position(self, msg) -> None:
        self.home_ned = (float(msg.x), float(msg.y))

    def _sample(self, time_boot_ms: int, x: float, y: float, geodetic: bool = False) -> None:
        """A sample at (x, y) [m], or at latitude x, longitude y [deg] when ``geodetic``."""
        b = self.battery
        if b.voltage_V is None or b.current_A is None:
            self.tell("battery_unknown", "no battery voltage and current yet: positions "
                                         "wait for them")
            return
        t = self._mission_time(time_boot_ms)
        if t is None:
            return
        self._t_last = t
        row = {"t_s": t, "x_m": x, "y_m": y, "voltage_V": b.voltage_V, "current_A": b.current_A,
               "_geodetic": geodetic}
        if b.soc is not None:
            row["soc"] = b.soc
        if self.wind is not None:
            row["wind_mps"], row["wind_from_deg"] = self.wind
        self.samples.append(row)
        self.arrived.append(self.clock())

    # --- battery and wind ----------------------------------------------------------------
    def _on_battery_status(self, msg) -> None:
        if msg.id != 0:  # the first battery powers the vehicle
            return
        cells = [v for v in msg.voltages if v != UINT16_UNKNOWN]
        self._battery(sum(cells) / 1000.0 if cells else None, msg.current_battery,
                      msg.battery_remaining, "BATTERY_STATUS")

    def _on_sys_status(self, msg) -> None:
        volts = None if msg.voltage_battery == UINT16_UNKNOWN else msg.voltage_battery / 1000.0
        self._battery(volts, msg.current_battery, msg.battery_remaining, "SYS_STATUS")

    def _battery(self, volts, current_cA: int, remaining: int, where: str) -> None:
        unknown = []
        if volts is None or not volts > 0:
            unknown.append("voltage")
        else:
            self.battery.voltage_V = volts
        if current_cA == INT_UNKNOWN:
            unknown.append("current")
        else:
            self.battery.current_A = current_cA / 100.0
        if remaining == INT_UNKNOWN or not 0 <= remaining <= 100:
            unknown.append("remaining")
        else:
            self.battery.soc = remaining / 100.0
        if unknown:
            self.tell(f"battery_{'_'.join(unknown)}",
                      f"{where} without {', '.join(unknown)} (marked unknown): the last known "
                      "value stands")

    def _on_wind(self, msg) -> None:  # ArduPilot: speed and the direction it comes from
        if math.isfinite(msg.speed) and math.isfinite(msg.direction):
            self.wind = (float(msg.speed), float(msg.direction) % 360.0)

    def _on_wind_cov(self, msg) -> None:  # PX4: the air's velocity, north and east
        if math.isfinite(msg.wind_x) and math.isfinite(msg.wind_y):
            speed, from_deg = wind_speed_and_from(float(msg.wind_y), float(msg.wind_x))
            self.wind = (float(speed), float(from_deg))

    def pop(self) -> tuple[list[dict], list[float]]:
        """The samples made since the last call and their arrival times."""
        rows, arrived = self.samples, self.arrived
        self.samples, self.arrived = [], []
        placed = [r for r in rows if r.pop("_geodetic")]
        if placed:
            lat = np.array([r["x_m"] for r in placed], float)
            lon = np.array([r["y_m"] for r in placed], float)
            x, y = latlon_to_xy(self.origin, lat, lon)
            for r, xi, yi in zip(placed, np.atleast_1d(x), np.atleast_1d(y)):
                r["x_m"], r["y_m"] = float(xi), float(yi)
        return rows, arrived
