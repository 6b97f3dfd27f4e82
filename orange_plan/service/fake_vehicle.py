"""A simulated vehicle speaking MAVLink: a plan flown in the project's simulator, in real or
accelerated time, for trying ``watch`` on one machine with no autopilot installed.

What it does: it sits on the ground at home (telemetry flowing, motors off) until it hears
a ground station report or command (a mission download does not count: the watch is not
ready yet) or ``takeoff_after_s`` passes, then flies the plan's tour under the truth
(``sim.simulator.simulate``; a heavier truth than the scenario makes the battery run short)
and sends, per simulated sample, ``GLOBAL_POSITION_INT``, ``LOCAL_POSITION_NED`` and
``BATTERY_STATUS``, and once a simulated second ``HEARTBEAT``, ``SYS_STATUS``, the wind
(``WIND_COV`` as PX4, ``WIND`` as ArduPilot) and ``HOME_POSITION``. It answers the mission
download (``MISSION_REQUEST_LIST`` -> ``MISSION_COUNT`` -> ``MISSION_ITEM_INT`` per request)
with the plan exported as the autopilot would fly it (``export.autopilot.build_mission``),
and ``MAV_CMD_NAV_RETURN_TO_LAUNCH`` with a ``COMMAND_ACK``: accepted, it flies home from
where it is (straight, or the roadmap's way round obstacles) and lands. If the battery's
usable energy runs out first it stops where it is: stranded.

The battery reports a constant pack voltage and the current that gives the simulated power
(``P = V I``); the time since boot runs at the simulated rate (``speedup`` x the wall clock).
The flight is scored as the benchmarks score theirs (``sim.flight.Flown.outcome``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from orange_plan.errors import InputError, check_range
from orange_plan.export.autopilot import build_mission, check_firmware, enu_to_geodetic
from orange_plan.service.mavlink_link import (
    degE7,
    item_from_message,
    send_mission_item,
    text_bytes,
)
from orange_plan.sim.flight import Flown, simulate_route

MAX_SPEEDUP = 1000.0
"""Fastest time acceleration [-]: beyond it one simulated second is under a millisecond of
wall time, shorter than a loopback round trip."""
BOOT_S = 10.0
"""Time since boot when the vehicle starts to report [s] (an autopilot boots first)."""
GCS_TYPES = (6,)
"""MAV_TYPE of a ground station (MAV_TYPE_GCS)."""
MAV_RESULT = {"accepted": 0, "temporarily_rejected": 1, "denied": 2, "unsupported": 3}


@dataclass(frozen=True)
class VehicleOptions:
    """How the simulated vehicle flies and talks.

    Attributes
    ----------
    speedup : simulated seconds per wall second [-]
    rate_Hz : telemetry (and simulation) rate [Hz]
    altitude_m : flight altitude above home of an aerial vehicle [m]
    firmware : "px4" (``WIND_COV``) or "ardupilot" (``WIND``)
    voltage_V : the pack voltage reported [V]
    takeoff_after_s : wall seconds on the ground before take-off when no ground station
        speaks first (a report or a command: a mission download does not count)
    linger_s : wall seconds of telemetry after landing (or stranding) before it stops
    refuse_rtl : the first this many return-to-launch commands are answered
        "temporarily rejected" (a busy autopilot), the next ones accepted
    seed : simulator seed (gusts, noise)
    """

    speedup: float = 1.0
    rate_Hz: float = 10.0
    altitude_m: float = 20.0
    firmware: str = "px4"
    voltage_V: float = 11.1
    takeoff_after_s: float = 5.0
    linger_s: float = 2.0
    refuse_rtl: int = 0
    seed: int = 0

    def __post_init__(self):
        check_range(self.speedup, "--speedup", high=MAX_SPEEDUP)
        check_range(self.rate_Hz, "--rate-hz", high=100.0)
        check_range(self.voltage_V, "--voltage-V", high=1000.0)
        check_range(self.takeoff_after_s, "--takeoff-after-s", high=3600.0, low_open=False)
        check_range(self.linger_s, "--linger-s", high=3600.0, low_open=False)
        check_firmware(self.firmware, "--firmware")


@dataclass
class _Segment:
    """One simulated route being streamed: its recording, where the stream is, and the
    mission time and energy it started from."""

    frame: object
    lat: np.ndarray
    lon: np.ndarray
    t0_s: float
    used_J: np.ndarray  # battery energy drawn by each sample's end, the flight's so far [J]
    k: int = 0
    home: bool = False

    def __len__(self) -> int:
        return len(self.frame)


@dataclass
class FlightLog:
    """What happened: the outcome's inputs."""

    rtl_commands: int = 0
    rtl_accepted_t_s: float | None = None
    mission_downloads: int = 0
    uploads: int = 0
    events: list = field(default_factory=list)


class FakeVehicle:
    """The simulated vehicle (module docstring) on an open pymavlink ``link``.

    Parameters
    ----------
    ctx : Context (scenario, world with an ``origin``, model)
    xy_m, speed_mps : the tour to fly [m], [m/s]
    truth : ``sim.truth.Truth`` (None: the scenario's own model)
    link : pymavlink connection (``mavlink_link.open_link``)
    options : VehicleOptions
    say : callable taking one line of text (what the vehicle does)
    """

    def __init__(self, ctx, xy_m, speed_mps, truth, link, options: VehicleOptions,
                 say=print, clock=time.monotonic, sleep=time.sleep):
        self.ctx, self.truth, self.link, self.opt = ctx, truth, link, options
        self.say, self.clock, self.sleep = say, clock, sleep
        self.origin = getattr(ctx.world.map, "origin", None)
        if self.origin is None:
            raise InputError(f"{ctx.world.map.path}: the map has no 'origin' (the WGS84 point "
                             "at x = y = 0), so the vehicle cannot report latitude/longitude")
        self.aerial = ctx.scenario.robot.kind == "aerial"
        altitude = options.altitude_m if self.aerial else None
        self.mission = build_mission(ctx.world, ctx.scenario.robot.kind, xy_m, speed_mps,
                                     altitude, options.firmware, "fake-vehicle plan")
        self.xy_m, self.speed_mps = np.asarray(xy_m, float), np.asarray(speed_mps, float)
        self.home_xy = np.asarray(ctx.world.home_xy_m, float)
        self.flown = Flown(1.0 / options.rate_Hz, [], [], math.nan)
        self.log = FlightLog()
        self.segment: _Segment | None = None
        self.state = "ground"  # ground -> flying -> returning -> landed | stranded
        self.heard_gcs = False
        self._wall0 = None
        self._takeoff_boot_s = BOOT_S
        self._next_second = 0.0

    # --- clock -------------------------------------------------------------------------
    def boot_s(self) -> float:
        """Time since boot now, on the accelerated clock [s]."""
        return BOOT_S + (self.clock() - self._wall0) * self.opt.speedup

    def _wait_until_boot(self, boot_s: float) -> None:
        """Sleep until the accelerated clock reaches ``boot_s``, answering the link."""
        while True:
            self._answer()
            left = (boot_s - self.boot_s()) / self.opt.speedup
            if left <= 0:
                return
            self.sleep(min(left, 0.02))

    # --- the flight --------------------------------------------------------------------
    def run(self, stop_when=None) -> dict:
        """Fly: ground wait, the plan (or the way home after an RTL), landing; the outcome.
        ``stop_when()`` true ends the flight where it is (a benchmark's time is up)."""
        self._wall0 = self.clock()
        self._on_ground()
        self.state = "flying"
        self.say(f"take-off at {self.boot_s():.1f} s since boot")
        self._takeoff_boot_s = self.boot_s()
        self.segment = self._simulate(self.xy_m, self.speed_mps, 0.0, 0.0)
        while self.state in ("flying", "returning"):
            if stop_when is not None and stop_when():
                break
            self._stream_one()
        self._linger()
        return self.outcome()

    def _on_ground(self) -> None:
        dt = 1.0 / self.opt.rate_Hz
        start_wall = self.clock()
        boot = self.boot_s()
        while not self.heard_gcs and self.clock() - start_wall < self.opt.takeoff_after_s:
            self._send_sample(boot, self.home_xy, 0.0, (0.0, 0.0), 0.0, 0.0, 1.0, None)
            boot += dt
            self._wait_until_boot(boot)

    def _simulate(self, xy, speed, t0_s: float, energy0_J: float) -> _Segment:
        sim = simulate_route(self.ctx, xy, speed, self.truth, self.opt.seed, self.opt.rate_Hz,
                             energy0_J)
        self.flown.e_avail = sim.energy_available_J
        frame = sim.frame
        lat, lon, _ = enu_to_geodetic(self.origin, frame["x_m"].to_numpy(float),
                                      frame["y_m"].to_numpy(float))
        used = energy0_J + np.cumsum(frame["power_W"].to_numpy(float)) / self.opt.rate_Hz
        return _Segment(frame, np.atleast_1d(lat), np.atleast_1d(lon), t0_s, used)

    def _stream_one(self) -> None:
        """Send the segment's next sample at its time; end the segment, land or strand."""
        seg = self.segment
        if seg.k >= len(seg):
            self.flown.add(seg.frame)
            self._land()
            return
        row = seg.frame.iloc[seg.k]
        t = seg.t0_s + float(row["t_s"])
        used = float(seg.used_J[seg.k])
        self._wait_until_boot(self._takeoff_boot_s + t)
        if self.segment is not seg:  # an RTL arrived while waiting
            return
        if used > self.flown.e_avail:
            self.flown.add(seg.frame, seg.k + 1)
            self._strand(t)
            return
        xy = (float(row["x_m"]), float(row["y_m"]))
        wind = (float(row["wind_mps"]), float(row["wind_from_deg"])) if "wind_mps" in row \
            else (0.0, 0.0)
        soc = max(0.0, 1.0 - used / self.flown.e_avail)
        self._send_sample(self._takeoff_boot_s + t, xy, float(row["v_mps"]), wind,
                          float(row["power_W"]), used, soc, (seg.lat[seg.k], seg.lon[seg.k]))
        seg.k += 1

    def _return_home(self) -> None:
        """Cut the flight where it is and fly the way home (RTL accepted)."""
        self._fly_from_here(None, returning=True)

    def _fly_from_here(self, points, returning: bool) -> None:
        """Cut the flight where it is and fly ``points`` from here (None: the way home)."""
        k, here, t_here = self._here()
        self.flown.add(self.segment.frame, k)
        path = self._way_home(here) if points is None else _distinct(np.vstack([here, points]))
        if len(path) < 2:
            self._land()
            return
        speed = np.full(len(path), self.ctx.cruise_speed_mps)
        self.segment = self._simulate(path, speed, t_here + 1.0 / self.opt.rate_Hz,
                                      self.flown.energy_drawn_J)
        self.segment.home = returning
        self.state = "returning" if returning else "flying"

    def _here(self) -> tuple[int, np.ndarray, float]:
        """(samples flown in the segment, the position [m], the flight time [s]) now."""
        seg = self.segment
        k = max(seg.k, 1)
        here = seg.frame[["x_m", "y_m"]].to_numpy(float)[k - 1]
        return k, here, seg.t0_s + float(seg.frame["t_s"].iloc[k - 1])

    def _way_home(self, here) -> np.ndarray:
        """Straight home when the map allows it, else the roadmap's way round."""
        straight = np.vstack([here, self.home_xy])
        if float(np.hypot(*(straight[1] - straight[0]))) < 1e-6:
            return straight[:1]
        try:
            self.ctx.world.check_route(straight, "the way home")
            return straight
        except InputError:
            from orange_plan.planning.homepaths import HomePaths
            from orange_plan.planning.reach import prepare_reach

            return HomePaths(prepare_reach(self.ctx, n_vertices=1000)).path(here)

    def _land(self) -> None:
        self.state = "landed"
        out = self.outcome()
        self.say(f"landed {out['distance_from_home_m']:.1f} m from home with "
                 f"{out['energy_left_J']:,.0f} J left")
        self._status(6, f"landed, {out['energy_left_J']:.0f} J left")

    def _strand(self, t: float) -> None:
        self.state = "stranded"
        self.say(f"battery empty {t:.1f} s after take-off: stranded "
                 f"{self.outcome()['distance_from_home_m']:.0f} m from home")
        self._status(2, "battery empty: stranded")

    def _linger(self) -> None:
        end = self.clock() + self.opt.linger_s
        dt = 1.0 / self.opt.rate_Hz
        boot = self.boot_s()
        while self.clock() < end:
            self._heartbeat()
            boot += max(dt, 1.0)
            self._wait_until_boot(boot)

    # --- scoring -----------------------------------------------------------------------
    def outcome(self) -> dict:
        """``Flown.outcome`` and what the link saw (docs/json.md, fake-vehicle)."""
        if not self.flown.xy:
            return {"state": self.state, "energy_left_J": self.flown.e_avail,
                    "energy_used_J": 0.0, "energy_available_J": self.flown.e_avail,
                    "distance_from_home_m": 0.0, "stranded": False, "duration_s": 0.0,
                    "rtl_commands": self.log.rtl_commands,
                    "rtl_accepted_t_s": self.log.rtl_accepted_t_s,
                    "mission_downloads": self.log.mission_downloads,
                    "mission_uploads": self.log.uploads}
        scored = self.flown.outcome(self.ctx)
        last = np.vstack(self.flown.xy)[-1]
        return {"state": self.state, "energy_left_J": scored["energy_left_J"],
                "energy_used_J": self.flown.energy_drawn_J,
                "energy_available_J": self.flown.e_avail,
                "distance_from_home_m": float(np.hypot(*(last - self.home_xy))),
                "stranded": bool(scored["stranded"]), "duration_s": scored["duration_s"],
                "rtl_commands": self.log.rtl_commands,
                "rtl_accepted_t_s": self.log.rtl_accepted_t_s,
                "mission_downloads": self.log.mission_downloads,
                "mission_uploads": self.log.uploads}

    # --- sending -----------------------------------------------------------------------
    def _send_sample(self, boot_s, xy, speed, wind, power, used, soc, latlon) -> None:
        mav, ms = self.link.mav, round(boot_s * 1000)
        if latlon is None:
            lat, lon, _ = enu_to_geodetic(self.origin, *xy)
        else:
            lat, lon = latlon
        flying = self.state in ("flying", "returning")
        alt = self.opt.altitude_m if (flying and self.aerial) else 0.0
        east, north = xy[0] - self.home_xy[0], xy[1] - self.home_xy[1]
        mav.global_position_int_send(ms, degE7(lat), degE7(lon),
                                     round((self.origin.alt_m + alt) * 1000),
                                     round(alt * 1000), 0, 0, 0, 65535)
        mav.local_position_ned_send(ms, north, east, -alt, 0.0, 0.0, 0.0)
        volts = self.opt.voltage_V
        current_cA = round(power / volts * 100) if flying else 0
        mav.battery_status_send(0, 0, 0, 32767, [round(volts * 1000)] + [65535] * 9,
                                current_cA, round(used / volts / 3.6),
                                round(used / 100), round(100 * soc))
        if boot_s >= self._next_second:
            self._next_second = boot_s + 1.0
            self._heartbeat()
            mav.sys_status_send(0, 0, 0, 0, round(volts * 1000), current_cA,
                                round(100 * soc), 0, 0, 0, 0, 0, 0)
            self._send_wind(*wind)
            self._send_home()

    def _send_home(self, north_m: float = 0.0, east_m: float = 0.0) -> None:
        """HOME_POSITION: the mission's home, at (north, east) in the local frame [m]."""
        self.link.mav.home_position_send(
            degE7(self.mission.home_lat_deg), degE7(self.mission.home_lon_deg),
            round(self.origin.alt_m * 1000), north_m, east_m, 0.0, [1.0, 0.0, 0.0, 0.0],
            0.0, 0.0, 0.0)

    def _send_wind(self, speed_mps: float, from_deg: float) -> None:
        from orange_plan.physics.wind import wind_xy_mps

        if self.opt.firmware == "ardupilot":
            self.link.mav.wind_send(from_deg, speed_mps, 0.0)
        else:
            east, north = wind_xy_mps(speed_mps, from_deg)
            self.link.mav.wind_cov_send(0, north, east, 0.0, math.nan, math.nan, math.nan,
                                        math.nan, math.nan)

    def _heartbeat(self) -> None:
        # base_mode: custom mode enabled (1), armed (128) while in the air
        armed = 128 if self.state in ("flying", "returning") else 0
        status = {"ground": 3, "flying": 4, "returning": 4, "landed": 3, "stranded": 6}
        self.link.mav.heartbeat_send(self.mission.vehicle_type, self.mission.firmware_type,
                                     1 | armed, 0, status[self.state])

    def _status(self, severity: int, text: str) -> None:
        self.link.mav.statustext_send(severity, text_bytes(text, 50))

    # --- answering ---------------------------------------------------------------------
    def _answer(self) -> None:
        """Every message waiting on the link, without blocking."""
        while True:
            msg = self.link.recv_match(blocking=False)
            if msg is None:
                return
            kind = msg.get_type()
            if kind == "BAD_DATA":
                continue
            # a ground station's report or command: it is watching (a mission download
            # alone comes before the watch is ready)
            self.heard_gcs |= not kind.startswith("MISSION_")
            handler = getattr(self, f"_on_{kind.lower()}", None)
            if handler is not None:
                handler(msg)

    def _on_command_long(self, msg) -> None:
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if msg.command != 20:  # MAV_CMD_NAV_RETURN_TO_LAUNCH
            self.link.mav.command_ack_send(msg.command, MAV_RESULT["unsupported"], 0, 0, *src)
            return
        self.log.rtl_commands += 1
        if self.log.rtl_commands <= self.opt.refuse_rtl:
            self.say("return-to-launch refused (temporarily rejected)")
            self.link.mav.command_ack_send(20, MAV_RESULT["temporarily_rejected"], 0, 0, *src)
            return
        if self.state not in ("flying", "returning"):
            self.link.mav.command_ack_send(20, MAV_RESULT["denied"], 0, 0, *src)
            return
        self.link.mav.command_ack_send(20, MAV_RESULT["accepted"], 0, 0, *src)
        if self.state == "flying":
            seg = self.segment
            t = seg.t0_s + float(seg.frame["t_s"].iloc[max(seg.k, 1) - 1])
            self.log.rtl_accepted_t_s = t
            self.say(f"return-to-launch accepted at {self.boot_s():.1f} s since boot "
                     f"({t:.1f} s after take-off)")
            self._status(4, "RTL accepted: returning home")
            self._return_home()

    def _on_mission_request_list(self, msg) -> None:
        self.log.mission_downloads += 1
        self.link.mav.mission_count_send(msg.get_srcSystem(), msg.get_srcComponent(),
                                         len(self.mission.items), 0)

    def _on_mission_request_int(self, msg) -> None:
        if 0 <= msg.seq < len(self.mission.items):
            send_mission_item(self.link.mav, (msg.get_srcSystem(), msg.get_srcComponent()),
                              msg.seq, self.mission.items[msg.seq])

    _on_mission_request = _on_mission_request_int  # the older float request

    # --- mission upload: MISSION_COUNT, then MISSION_REQUEST_INT per item, MISSION_ACK ------
    def _on_mission_count(self, msg) -> None:
        if msg.mission_type != 0 or not 0 < msg.count <= 10_000:
            return
        self._upload = {"from": (msg.get_srcSystem(), msg.get_srcComponent()),
                        "count": msg.count, "items": []}
        self.link.mav.mission_request_int_send(*self._upload["from"], 0, 0)

    def _on_mission_item_int(self, msg) -> None:
        up = getattr(self, "_upload", None)
        if up is None or msg.seq != len(up["items"]):
            return
        up["items"].append(item_from_message(msg))
        if len(up["items"]) < up["count"]:
            self.link.mav.mission_request_int_send(*up["from"], len(up["items"]), 0)
            return
        self._upload = None
        accepted = self.state == "flying" and self._fly_uploaded(up["items"])
        self.link.mav.mission_ack_send(*up["from"], 0 if accepted else 1, 0)  # 1: MAV_MISSION_ERROR

    def _fly_uploaded(self, items) -> bool:
        """Fly an uploaded mission from where the vehicle is; False when it cannot be read."""
        from orange_plan.export.missions_in import mission_from_items

        home = (self.mission.home_lat_deg, self.mission.home_lon_deg, self.origin.alt_m)
        try:
            mission = mission_from_items(home, items, self.origin, "uploaded mission")
        except InputError as exc:
            self.say(f"mission upload refused: {exc}")
            return False
        points = [(w.x_m, w.y_m) for w in mission.waypoints[1:]]  # [0] is home
        if mission.returns_home:
            points.append(tuple(self.home_xy))
        path = _distinct(np.vstack([self._here()[1], points]))
        try:
            self.ctx.world.check_route(path, "uploaded mission")
        except InputError as exc:
            self.say(f"mission upload refused: {exc}")
            return False
        self.log.uploads += 1
        self.say(f"new mission uploaded ({len(items)} items): flying it from here")
        self._status(6, "mission uploaded: flying it")
        self._fly_from_here(np.array(points, float), returning=False)
        return True


def _distinct(path: np.ndarray) -> np.ndarray:
    """The path without repeated consecutive vertices."""
    keep = np.r_[True, np.hypot(*np.diff(path, axis=0).T) > 1e-6]
    return path[keep]
