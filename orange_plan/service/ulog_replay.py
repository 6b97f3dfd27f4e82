"""A PX4 flight log replayed as MAVLink: a real-data feed for ``watch``.

The log is read by the recording importer (``telemetry.importers.ulog.read_ulog``:
``battery_status`` and ``vehicle_local_position`` on the battery's time grid) and sent in
real or accelerated time as the vehicle sent it: ``LOCAL_POSITION_NED`` in the log's own
local frame, ``HOME_POSITION`` at the log's first position, ``BATTERY_STATUS`` and
``SYS_STATUS`` per battery sample with the fields the log does not know marked unknown
(``UINT16_MAX`` voltage, ``-1`` current or remaining), and a ``HEARTBEAT`` each second. It
starts when a ground station reports or commands (or ``takeoff_after_s`` passes). A watch places the
flight at its map's home. The mission it serves for download is the flown track (placed the
same way, decimated as an export would); return-to-launch is answered "denied" and a mission
upload refused: a recorded flight cannot turn.
"""

from __future__ import annotations

import math

import numpy as np

from orange_plan.errors import InputError
from orange_plan.service.fake_vehicle import MAV_RESULT, FakeVehicle
from orange_plan.service.mavlink_link import INT_UNKNOWN, UINT16_UNKNOWN

TRACK_STEP_S = 1.0
"""Time between the track points offered as the mission's waypoints [s] (decimated again
by the export's rule)."""


class UlogReplay(FakeVehicle):
    """A recorded PX4 flight streamed on an open pymavlink ``link``.

    Parameters
    ----------
    ctx : Context whose map has an ``origin`` (the track is placed at its home)
    frame : the log as a recording table (``read_ulog``)
    link, options, say : as ``FakeVehicle`` (the options' speedup, altitude and timings)
    """

    def __init__(self, ctx, frame, link, options, say=print, **kwargs):
        placed = frame.dropna(subset=["x_m", "y_m"])
        if placed.empty:
            raise InputError("the log has no position on its battery's time grid")
        self.first_local = placed[["x_m", "y_m"]].to_numpy(float)[0]
        home = np.asarray(ctx.world.home_xy_m, float)
        step = max(1, round(TRACK_STEP_S / _median_dt(placed["t_s"])))
        track = placed[["x_m", "y_m"]].to_numpy(float)[::step] - self.first_local + home
        track = np.vstack([home, track[1:], placed[["x_m", "y_m"]].to_numpy(float)[-1:]
                           - self.first_local + home])
        try:
            super().__init__(ctx, track, np.full(len(track), ctx.cruise_speed_mps), None, link,
                             options, say=say, **kwargs)
        except InputError as exc:
            raise InputError(f"the log's track placed at the map's home does not fit the map "
                             f"({exc})") from None
        self.frame = frame.reset_index(drop=True)
        self.sent = 0

    def run(self, stop_when=None) -> dict:
        """Stream the log row by row at its times; a summary."""
        self._wall0 = self.clock()
        self._wait_for_ground_station()
        self.state = "flying"
        self._takeoff_boot_s = self.boot_s()
        t0 = float(self.frame["t_s"].iloc[0])
        for row in self.frame.itertuples(index=False):
            if stop_when is not None and stop_when():
                break
            boot = self._takeoff_boot_s + float(row.t_s) - t0
            self._wait_until_boot(boot)
            self._send_row(boot, row)
        self.state = "landed"
        self._linger()
        return self.outcome()

    def _wait_for_ground_station(self) -> None:
        """Heartbeats until a ground station reports or commands (``takeoff_after_s``)."""
        start, boot = self.clock(), self.boot_s()
        while not self.heard_gcs and self.clock() - start < self.opt.takeoff_after_s:
            self._heartbeat()
            self._send_home(self.first_local[1], self.first_local[0])
            boot += 1.0
            self._wait_until_boot(min(boot, self.boot_s() + 0.2 * self.opt.speedup))

    def _send_row(self, boot_s: float, row) -> None:
        mav, ms = self.link.mav, round(boot_s * 1000)
        if boot_s >= self._next_second:  # home first: a local position needs it
            self._next_second = boot_s + 1.0
            self._heartbeat()
            self._send_home(self.first_local[1], self.first_local[0])
        volts = float(row.voltage_V)
        current = float(row.current_A)
        soc = float(getattr(row, "soc", math.nan))
        mV = round(volts * 1000) if math.isfinite(volts) and 0 < volts < 65.5 else UINT16_UNKNOWN
        cA = round(current * 100) if math.isfinite(current) else INT_UNKNOWN
        remaining = round(100 * soc) if math.isfinite(soc) and 0 <= soc <= 1 else INT_UNKNOWN
        mav.battery_status_send(0, 0, 0, 32767, [mV] + [UINT16_UNKNOWN] * 9, cA, -1, -1,
                                remaining)
        x, y = float(row.x_m), float(row.y_m)
        if math.isfinite(x) and math.isfinite(y):
            z = float(row.z_m) if math.isfinite(float(row.z_m)) else 0.0
            mav.local_position_ned_send(ms, y, x, -z, 0.0, 0.0, 0.0)
        mav.sys_status_send(0, 0, 0, 0, mV, cA, remaining, 0, 0, 0, 0, 0, 0)
        self.sent += 1

    def _on_command_long(self, msg) -> None:
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if msg.command == 20:
            self.log.rtl_commands += 1
            self.say("return-to-launch received: denied (a recorded flight cannot turn)")
        self.link.mav.command_ack_send(msg.command, MAV_RESULT["denied"], 0, 0, *src)

    def _on_mission_count(self, msg) -> None:
        """A mission upload is refused at once (MAV_MISSION_ERROR): the flight is recorded."""
        self.say("mission upload refused (a recorded flight cannot change)")
        self.link.mav.mission_ack_send(msg.get_srcSystem(), msg.get_srcComponent(), 1, 0)

    def outcome(self) -> dict:
        """What was replayed (docs/json.md, fake-vehicle --replay)."""
        f = self.frame
        # an unknown field counts at its last known value, as the watch takes it
        power = (f["voltage_V"].ffill() * f["current_A"].ffill()).to_numpy(float)
        dt = np.diff(f["t_s"].to_numpy(float), prepend=float(f["t_s"].iloc[0]))
        return {"state": "replayed", "samples_sent": self.sent, "samples": len(f),
                "duration_s": float(f["t_s"].iloc[-1] - f["t_s"].iloc[0]),
                "energy_used_J": float(np.nansum(power * dt)),
                "rtl_commands": self.log.rtl_commands,
                "mission_downloads": self.log.mission_downloads, "mission_uploads": 0}


def _median_dt(t) -> float:
    dt = np.diff(np.asarray(t, float))
    dt = dt[dt > 0]
    return float(np.median(dt)) if dt.size else TRACK_STEP_S
