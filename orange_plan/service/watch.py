"""``watch``: a MAVLink companion that feeds a vehicle's telemetry to a ``MissionSession``,
reports each decision, and with ``rtl`` sends the vehicle home in time.

Problem statement (kept apart from how it is solved): a vehicle streams its position
(``GLOBAL_POSITION_INT``, or ``LOCAL_POSITION_NED`` from ``HOME_POSITION``), its battery
(``BATTERY_STATUS`` / ``SYS_STATUS``: voltage, current, remaining) and the wind (``WIND`` from
ArduPilot, ``WIND_COV`` from PX4). The operator needs, live, the homing margin, the
probability of getting home and how far and how long until the point of no return; the
ground station needs the same; and, when allowed, the vehicle must be told to return while
the margin still covers the way home. A radio link drops, repeats and reorders messages, an
autopilot may reboot in flight, and a battery monitor may not know a field: each is said,
none may stop the watch, and the watch must never hold the vehicle's link.

How it is solved:

* ``TelemetryReader`` turns messages into session samples (``t_s``, ``x_m``, ``y_m``,
  ``voltage_V``, ``current_A``, ``soc``, ``wind_mps``, ``wind_from_deg``): positions through
  the map's ``origin`` (``export.autopilot.latlon_to_xy``); mission time from the vehicle's
  time since boot, the first position heard being ``FIRST_SAMPLE_S``; a position not newer
  than the last one is a duplicate or out of order and is dropped (counted and said); a time
  since boot that falls back by more than ``REBOOT_BACKSTEP_S`` is a reboot: mission time goes
  on from where it was. Battery fields marked unknown (``UINT16_MAX`` voltage, ``-1`` current
  or remaining) keep the last known value; until voltage and current are both known no
  sample is made.
* ``Watch.tick`` feeds the samples gathered since the last decision as one batch
  (``MissionSession.feed``), reports the decision on the terminal (a line per
  ``line_every_s`` and on every change of action), to the ground station (``NAMED_VALUE_FLOAT``
  ``NAMED_VALUES``; ``STATUSTEXT`` on every change of action) and in the JSON log.
* The point of no return: where the homing margin reaches zero if it keeps falling at the
  rate it fell over the last ``PNR_WINDOW_S`` of mission time, per second and per metre
  flown (a least-squares slope); no point ahead (None) while the margin does not fall.
* With ``upload``, a ``replan`` decision plans a new tour on a copy of the session (a thread:
  decisions go on), shows it, and asks the operator on the terminal; only a typed ``y``
  uploads it (``MISSION_COUNT``, then ``MISSION_ITEM_INT`` per request, ``MISSION_ACK``), and
  only a mission the vehicle accepted becomes the session's plan.
* The watch sends its own ``HEARTBEAT`` once a second (a companion computer, with no
  autopilot), as MAVLink components do.
* With ``rtl``, the first ``return_home`` sends ``MAV_CMD_NAV_RETURN_TO_LAUNCH`` once; a
  ``COMMAND_ACK`` other than accepted, or none within ``ack_timeout_s``, sends it again, at
  most ``rtl_attempts`` times in all. Without ``rtl`` no command is ever sent.
* The link is read by a thread of its own (``run_watch``): a slow decision never leaves the
  socket unread; decisions take the queued messages for at most ``DRAIN_S`` at a time. A
  link silent for ``silent_s`` is said once, and its return too.
"""

from __future__ import annotations

import json
import math
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from orange_plan.errors import InputError, check_range
from orange_plan.export.autopilot import MAX_ALTITUDE_M, latlon_to_xy
from orange_plan.physics.wind import wind_speed_and_from
from orange_plan.service.mavlink_link import INT_UNKNOWN, UINT16_UNKNOWN, text_bytes

FIRST_SAMPLE_S = 0.1
"""Mission time of the first position heard [s] (a session starts at 0 at home)."""
REBOOT_BACKSTEP_S = 2.0
"""A time since boot that falls back by more than this is a reboot, not a late message [s]."""
PNR_WINDOW_S = 60.0
"""Mission time over which the margin's fall is measured for the point of no return [s]."""
NAMED_VALUES = {"homing_margin_J": "op_margin", "return_probability": "op_p_home",
                "pnr_time_s": "op_pnr_s", "pnr_distance_m": "op_pnr_m"}
"""Decision figure -> NAMED_VALUE_FLOAT name (at most 10 characters) sent to the ground."""
RTL = 20
"""MAV_CMD_NAV_RETURN_TO_LAUNCH."""
ACK_RESULTS = {0: "accepted", 1: "temporarily rejected", 2: "denied", 3: "unsupported",
               4: "failed", 5: "in progress", 6: "cancelled"}
SEVERITY = {"return_home": 2, "replan": 4, "continue": 6}
"""STATUSTEXT severity per action: critical, warning, info (a flag: warning)."""
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


@dataclass(frozen=True)
class WatchOptions:
    """How the watch reports and acts.

    Attributes
    ----------
    rtl : send return-to-launch when the decision is ``return_home``
    upload : on a ``replan`` decision, plan a new tour and, once the operator confirms it
        on the terminal, upload it with the mission protocol
    altitude_m, firmware : the flight altitude above home [m] and the autopilot
        ("px4" or "ardupilot") of an uploaded mission (``export.autopilot.build_mission``)
    rtl_attempts : most return-to-launch commands (and mission uploads) sent before giving
        up [-]
    ack_timeout_s : wall seconds to wait for a COMMAND_ACK before sending again
    silent_s : wall seconds without a message after which the link is said silent
    line_every_s : wall seconds between live lines with the same action
    report_every_s : wall seconds between NAMED_VALUE_FLOAT reports
    """

    rtl: bool = False
    upload: bool = False
    altitude_m: float = 20.0
    firmware: str = "px4"
    rtl_attempts: int = 3
    ack_timeout_s: float = 1.5
    silent_s: float = 3.0
    line_every_s: float = 1.0
    report_every_s: float = 0.5

    def __post_init__(self):
        if not (isinstance(self.rtl_attempts, int) and 1 <= self.rtl_attempts <= 20):
            raise InputError(f"--rtl-attempts = {self.rtl_attempts!r} must be 1 to 20")
        if self.firmware not in ("px4", "ardupilot"):
            raise InputError(f"--firmware {self.firmware!r} must be px4 or ardupilot")
        check_range(self.altitude_m, "--altitude-m", high=MAX_ALTITUDE_M)
        check_range(self.ack_timeout_s, "--ack-timeout-s", high=3600.0)
        check_range(self.silent_s, "--silent-s", high=3600.0)


@dataclass
class _Rtl:
    """The return-to-launch exchange: attempts, when the last was sent, how it ended."""

    attempts: int = 0
    sent_at: float | None = None
    state: str = "idle"  # idle -> waiting -> accepted | failed


REPLAN_PAUSE_S = 60.0
"""Wall seconds after an upload (accepted, declined or failed) before another is offered."""


@dataclass
class _Upload:
    """The replan offered for upload: idle -> planning -> asking -> uploading -> idle."""

    state: str = "idle"
    plan: object = None
    items: tuple = ()
    attempts: int = 0
    sent_at: float = 0.0
    not_before: float = -math.inf
    worker: object = None
    result: list = field(default_factory=list)  # the worker's (plan, items) or error text


@dataclass
class _Trend:
    """Recent (mission time, distance flown, margin) of the decisions."""

    points: deque = field(default_factory=deque)
    distance_m: float = 0.0
    last_xy: tuple[float, float] | None = None


class Watch:
    """The watch on one vehicle (module docstring).

    Parameters
    ----------
    session : MissionSession of the mission flown
    origin : the map's WGS84 origin
    link : pymavlink connection (or an object with ``mav`` and its ``*_send`` methods)
    options : WatchOptions
    say : callable taking one line for the terminal
    log : callable taking one JSON-able dict per decision or event (the JSON log), or None
    """

    def __init__(self, session, origin, link, options: WatchOptions, say=print, log=None,
                 clock=time.monotonic):
        self.session, self.link, self.opt = session, link, options
        self.say_line, self.write_log, self.clock = say, log, clock
        self.reader = TelemetryReader(origin, tuple(session.ctx.world.home_xy_m), self._event,
                                      clock)
        self.rtl = _Rtl()
        self.up = _Upload()
        self.answers = queue.Queue()  # the operator's lines (``stdin_lines``)
        self.trend = _Trend()
        self.decisions = 0
        self.latencies_s: list[float] = []  # newest sample's arrival -> its decision [s]
        self.followed: list[tuple] = []  # (its time since boot [s], decision's wall time)
        self.last_action: str | None = None
        self._last_line = -math.inf
        self._last_report = -math.inf
        self._last_heard = clock()
        self._last_heartbeat = -math.inf
        self._silent = False
        self.last_decision = None

    # --- events ------------------------------------------------------------------------
    def _event(self, kind: str, text: str) -> None:
        self.say_line(f"[{kind}] {text}")
        self._log({"kind": "event", "event": kind, "message": text})

    def _log(self, record: dict) -> None:
        if self.write_log is not None:
            self.write_log({"unix_time_s": round(time.time(), 3), **record})

    # --- the link ------------------------------------------------------------------------
    def take(self, msg) -> None:
        """One message from the link."""
        kind = msg.get_type()
        if kind == "BAD_DATA":
            return
        self._heard()
        if kind == "COMMAND_ACK":
            self._on_ack(msg)
        elif kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"):
            self._on_mission(msg)
        elif kind == "STATUSTEXT" and msg.get_srcSystem() == self._vehicle_system():
            self._event("vehicle_text", str(msg.text).strip("\x00"))
        else:
            self.reader.take(msg)

    def _vehicle_system(self):
        return None if self.reader.vehicle is None else self.reader.vehicle[0]

    def silent_for_s(self) -> float:
        """Wall seconds since the last message [s]."""
        return self.clock() - self._last_heard

    def _heard(self) -> None:
        now = self.clock()
        if self._silent:
            self._silent = False
            self._event("link_back", f"the link is back after {now - self._last_heard:.1f} s "
                                     "of silence")
        self._last_heard = now

    def tick(self):
        """Feed what arrived, report, and drive the RTL exchange; the decision or None."""
        now = self.clock()
        if now - self._last_heartbeat >= 1.0:  # a companion announces itself once a second
            self._last_heartbeat = now
            self.link.mav.heartbeat_send(ONBOARD_CONTROLLER, INVALID_AUTOPILOT, 0, 0, 4)
        if not self._silent and now - self._last_heard > self.opt.silent_s:
            self._silent = True
            self._event("link_silent", f"no message from the vehicle for "
                                       f"{now - self._last_heard:.1f} s; the last decision "
                                       "stands until telemetry returns")
        self._rtl_timeouts(now)
        if self.opt.upload:
            self._upload_progress(now)
        rows, arrived = self.reader.pop()
        if not rows:
            return None
        try:
            decision = self.session.feed(rows)
        except InputError as exc:
            self._event("telemetry_refused", f"{len(rows)} sample(s) refused: {exc}")
            return None
        latency = self.clock() - arrived[-1]
        self.latencies_s.append(latency)
        self.followed.append((self.reader.boot_last_s, self.clock()))
        self.decisions += 1
        self.last_decision = decision
        self._report(decision, latency, len(rows))
        if decision.action == "return_home" and self.opt.rtl and self.rtl.state == "idle":
            self._send_rtl()
        if (self.opt.upload and decision.action == "replan" and self.up.state == "idle"
                and self.rtl.state == "idle" and self.clock() >= self.up.not_before):
            self._start_replan()
        return decision

    # --- reports ------------------------------------------------------------------------
    def point_of_no_return(self, decision) -> tuple[float | None, float | None]:
        """(time [s], distance [m]) to where the margin reaches zero at its recent fall
        (module docstring); None where it does not fall."""
        tr = self.trend
        xy = decision.position_xy_m
        if tr.last_xy is not None:
            tr.distance_m += math.hypot(xy[0] - tr.last_xy[0], xy[1] - tr.last_xy[1])
        tr.last_xy = xy
        margin = decision.homing_margin_J
        if not math.isfinite(margin):
            return None, None
        tr.points.append((decision.time_s, tr.distance_m, margin))
        while tr.points and tr.points[0][0] < decision.time_s - PNR_WINDOW_S:
            tr.points.popleft()
        if margin <= 0:
            return 0.0, 0.0
        if len(tr.points) < 3:
            return None, None
        t, s, m = (np.array(c, float) for c in zip(*tr.points))
        return _until_zero(t, m, margin), _until_zero(s, m, margin)

    def _report(self, decision, latency_s: float, n: int) -> None:
        pnr_s, pnr_m = self.point_of_no_return(decision)
        figures = {"homing_margin_J": decision.homing_margin_J,
                   "return_probability": decision.return_probability,
                   "pnr_time_s": pnr_s, "pnr_distance_m": pnr_m}
        now = self.clock()
        changed = decision.action != self.last_action
        self.last_action = decision.action
        if changed or now - self._last_line >= self.opt.line_every_s:
            self._last_line = now
            self.say_line(live_line(decision, pnr_s, pnr_m))
        if changed:
            self._statustext(SEVERITY.get(decision.action, 4),
                             f"orange: {decision.action.replace('_', ' ')} "
                             f"margin {_num(decision.homing_margin_J)} J")
        if now - self._last_report >= self.opt.report_every_s or changed:
            self._last_report = now
            ms = int(decision.time_s * 1000) & 0xFFFFFFFF
            for key, name in NAMED_VALUES.items():
                value = figures[key]
                self.link.mav.named_value_float_send(
                    ms, text_bytes(name, 10), float("nan") if value is None else float(value))
        self._log({"kind": "decision", **_finite(decision.to_dict()), "pnr_time_s": pnr_s,
                   "pnr_distance_m": pnr_m, "samples": n, "latency_s": round(latency_s, 4)})

    def _statustext(self, severity: int, text: str) -> None:
        self.link.mav.statustext_send(severity, text_bytes(text, 50))

    # --- return to launch ----------------------------------------------------------------
    def _send_rtl(self) -> None:
        vehicle = self.reader.vehicle
        if vehicle is None:
            self.reader.tell("rtl_no_vehicle", "return home decided but no vehicle HEARTBEAT "
                                               "heard yet: RTL waits for one")
            return
        rtl = self.rtl
        rtl.attempts += 1
        rtl.sent_at, rtl.state = self.clock(), "waiting"
        self.link.mav.command_long_send(vehicle[0], vehicle[1], RTL, rtl.attempts - 1,
                                        0, 0, 0, 0, 0, 0, 0)
        self._event("rtl_sent", f"return-to-launch sent (attempt {rtl.attempts} of "
                                f"{self.opt.rtl_attempts})")

    def _on_ack(self, msg) -> None:
        rtl = self.rtl
        if msg.command != RTL or rtl.state != "waiting":
            return
        result = ACK_RESULTS.get(msg.result, f"result {msg.result}")
        if msg.result == 0:
            rtl.state = "accepted"
            self._event("rtl_accepted", f"return-to-launch accepted (attempt {rtl.attempts})")
        elif msg.result == 5:  # in progress: wait on
            rtl.sent_at = self.clock()
        else:
            self._event("rtl_rejected", f"return-to-launch {result} (attempt {rtl.attempts})")
            self._retry_or_give_up()

    def _rtl_timeouts(self, now: float) -> None:
        rtl = self.rtl
        if rtl.state == "waiting" and now - rtl.sent_at > self.opt.ack_timeout_s:
            self._event("rtl_no_ack", f"no COMMAND_ACK for return-to-launch within "
                                      f"{self.opt.ack_timeout_s:g} s (attempt {rtl.attempts})")
            self._retry_or_give_up()

    def _retry_or_give_up(self) -> None:
        rtl = self.rtl
        if rtl.attempts < self.opt.rtl_attempts:
            rtl.state = "idle"
            self._send_rtl()
        else:
            rtl.state = "failed"
            self._event("rtl_failed", f"return-to-launch not accepted after {rtl.attempts} "
                                      "attempts: bring the vehicle home by hand")

    # --- a replanned mission, uploaded on the operator's word ------------------------------
    def _start_replan(self) -> None:
        """Plan a new tour on a copy of the session, in a thread: decisions go on meanwhile,
        and the session adopts the tour only once the vehicle has accepted it."""
        state = self.session.state_dict()
        self.up = _Upload(state="planning", not_before=self.up.not_before)
        self._event("replanning", "a replan is advised: planning a new tour (decisions go on)")
        self.up.worker = threading.Thread(target=_replan_copy, daemon=True, args=(
            self.session, state, self.opt, self.up.result), name="watch-replan")
        self.up.worker.start()

    def _upload_progress(self, now: float) -> None:
        up = self.up
        if up.state == "planning" and up.result:
            self._offer(up.result[0])
        elif up.state == "asking":
            try:
                answer = self.answers.get_nowait()
            except queue.Empty:
                return
            if answer.strip().lower() in ("y", "yes"):
                self._send_count()
            else:
                self._upload_done("upload_declined", "the operator kept the vehicle's mission")
        elif up.state == "uploading" and now - up.sent_at > self.opt.ack_timeout_s:
            if up.attempts < self.opt.rtl_attempts:
                self._send_count()
            else:
                self._upload_done("upload_failed", f"the vehicle did not take the mission "
                                                   f"after {up.attempts} attempts")

    def _offer(self, result) -> None:
        if isinstance(result, str):
            self._upload_done("replan_failed", result)
            return
        plan, items = result
        self.up.plan, self.up.items, self.up.state = plan, items, "asking"
        self._event("upload_asked", f"new tour: {len(plan.xy_m)} vertices, "
                                    f"{float(plan.summary.get('coverage_m2', 0.0)):,.0f} m^2 "
                                    f"more to sense, {len(items)} mission items")
        self.say_line("upload it to the vehicle? type y and Enter (anything else keeps the "
                      "vehicle's mission)")

    def _send_count(self) -> None:
        up, vehicle = self.up, self.reader.vehicle
        if vehicle is None:
            self._upload_done("upload_failed", "no vehicle HEARTBEAT heard")
            return
        up.attempts += 1
        up.state, up.sent_at = "uploading", self.clock()
        self.link.mav.mission_count_send(vehicle[0], vehicle[1], len(up.items), 0)
        self._event("upload_sent", f"mission upload started: {len(up.items)} items "
                                   f"(attempt {up.attempts})")

    def _on_mission(self, msg) -> None:
        from orange_plan.service.mavlink_link import send_mission_item

        up = self.up
        if up.state != "uploading" or msg.get_srcSystem() != self._vehicle_system():
            return
        up.sent_at = self.clock()
        if msg.get_type() == "MISSION_ACK":
            if msg.type == 0:  # MAV_MISSION_ACCEPTED: the vehicle flies it; so does the session
                self.session.adopt_stored_plan(up.plan.to_geojson())
                self._upload_done("upload_accepted", "the vehicle accepted the new mission")
            else:
                self._upload_done("upload_refused", f"the vehicle refused the mission "
                                                    f"(MAV_MISSION_RESULT {msg.type})")
        elif 0 <= msg.seq < len(up.items):
            send_mission_item(self.link.mav, self.reader.vehicle, msg.seq, up.items[msg.seq])

    def _upload_done(self, kind: str, text: str) -> None:
        self.up = _Upload(not_before=self.clock() + REPLAN_PAUSE_S)
        self._event(kind, text)

    # --- summary -------------------------------------------------------------------------
    def summary(self) -> dict:
        """What the watch saw and did (docs/json.md, watch)."""
        d = self.last_decision
        lat = np.asarray(self.latencies_s, float)
        return {"decisions": self.decisions, "last_action": None if d is None else d.action,
                "homing_margin_J": None if d is None else d.homing_margin_J,
                "energy_used_J": None if d is None else d.energy_used_J,
                "rtl_state": self.rtl.state, "rtl_attempts": self.rtl.attempts,
                "samples_dropped": self.reader.dropped, "reboots": self.reader.reboots,
                "latency_p95_s": float(np.percentile(lat, 95)) if lat.size else None}


def _until_zero(x: np.ndarray, margin: np.ndarray, now: float) -> float | None:
    """How much more of ``x`` until the margin reaches zero at its least-squares slope
    against ``x`` (None when it does not fall)."""
    dx = x - x.mean()
    denom = float(dx @ dx)
    if denom <= 0:
        return None
    slope = float(dx @ (margin - margin.mean())) / denom
    return now / -slope if slope < 0 else None


def _num(value) -> str:
    return "?" if value is None or not math.isfinite(value) else f"{value:,.0f}"


def _finite(d: dict) -> dict:
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in d.items()}


def live_line(decision, pnr_s, pnr_m) -> str:
    """The terminal line of a decision: time, action, margin, P(home), point of no return."""
    p = decision.return_probability
    prob = f"{p:.3f}" if math.isfinite(p) else "?"
    pnr = ("PNR passed" if pnr_s == 0 else
           "PNR -" if pnr_s is None or pnr_m is None else
           f"PNR in {pnr_s:,.0f} s / {pnr_m:,.0f} m")
    return (f"t {decision.time_s:7.1f} s  {decision.action:<12} margin "
            f"{_num(decision.homing_margin_J):>8} J  P(home) {prob}  {pnr}  used "
            f"{_num(decision.energy_used_J)} J")


def _replan_copy(session, state: dict, options, result: list) -> None:
    """The replanning thread: a copy of the session rebuilt from its events replans, and the
    new tour is exported as mission items; ``result`` gets (plan, items) or the reason."""
    from orange_plan.errors import OrangeError
    from orange_plan.export.autopilot import build_mission

    try:
        ctx = session.ctx
        copy = type(session).from_state(ctx, state)
        plan = copy.replan()
        altitude = options.altitude_m if ctx.scenario.robot.kind == "aerial" else None
        items = build_mission(ctx.world, ctx.scenario.robot.kind, plan.xy_m, plan.speed_mps,
                              altitude, options.firmware, "the replanned tour").items
        result.append((plan, items))
    except OrangeError as exc:
        result.append(f"no new tour to upload: {exc}")


def stdin_lines(answers: queue.Queue, stream=None) -> threading.Thread:
    """A thread putting each line typed on the terminal into ``answers``."""
    import sys

    def read():
        for line in stream or sys.stdin:
            answers.put(line)

    thread = threading.Thread(target=read, daemon=True, name="watch-stdin")
    thread.start()
    return thread


DRAIN_S = 0.1
"""Longest wall time spent taking queued messages before a decision [s]: a link that
delivers faster than the watch takes still gets a decision this often."""
QUEUE_MAX = 100_000
"""Messages the reading thread holds for the watch at most (~10 min of a 10 Hz vehicle's
stream); beyond it the oldest wait in the socket and, past its buffer, are lost (said)."""


def run_watch(link, watch: Watch, *, stop_after_s: float | None = None,
              stop_when=None, poll_s: float = 0.02, drain_s: float = DRAIN_S) -> None:
    """Read the link in a thread of its own and tick the watch until ``stop_after_s`` wall
    seconds pass or ``stop_when()`` is true.

    The reading thread empties the socket whatever the decisions cost (a slow decision must
    not let the socket's buffer overflow and lose telemetry); the caller's thread takes the
    queued messages for at most ``drain_s`` (waiting at most ``poll_s`` for the first), then
    ticks once.
    """
    inbox: queue.Queue = queue.Queue(maxsize=QUEUE_MAX)
    stop = threading.Event()
    notes: list[tuple[str, str]] = []  # what the reading thread has to say, said here
    reader = threading.Thread(target=_read_link, args=(link, inbox, stop, notes), daemon=True,
                              name="watch-link")
    reader.start()
    start = time.monotonic()
    try:
        while not ((stop_after_s is not None and time.monotonic() - start >= stop_after_s)
                   or (stop_when is not None and stop_when())):
            until = time.monotonic() + drain_s
            try:
                msg = inbox.get(timeout=poll_s)
                while True:
                    watch.take(msg)
                    if time.monotonic() >= until:
                        break
                    msg = inbox.get_nowait()
            except queue.Empty:
                pass
            while notes:
                watch.reader.tell(*notes.pop(0))
            watch.tick()
    finally:
        stop.set()
        reader.join(timeout=1.0)


def _read_link(link, inbox, stop, notes: list) -> None:
    """The reading thread: every message into ``inbox`` until ``stop`` is set; faults go to
    ``notes`` as (kind, text) for the watch's thread to say."""

    while not stop.is_set():
        try:
            msg = link.recv_match(blocking=True, timeout=0.05)
        except OSError as exc:  # a link that fails is said; the watch goes on without it
            notes.append(("link_error", f"the link failed to read: {exc}"))
            stop.wait(0.5)
            continue
        if msg is None:
            continue
        try:
            inbox.put(msg, timeout=0.5)
        except queue.Full:
            notes.append(("queue_full", "the watch falls behind the link: messages wait in "
                                        "the socket"))


def json_lines(path):
    """A JSON-lines writer for ``path`` (one object per line, flushed): returns
    (write, close)."""
    handle = open(path, "w", encoding="utf-8")  # noqa: SIM115 - closed by the caller

    def write(record: dict) -> None:
        handle.write(json.dumps(record) + "\n")
        handle.flush()

    return write, handle.close


# --- the plan flown ----------------------------------------------------------------------


def wait_for_vehicle(link, timeout_s: float) -> tuple[tuple[int, int], tuple | None]:
    """The vehicle's (system, component) from its HEARTBEAT and its home (lat, lon, alt AMSL)
    from HOME_POSITION, waiting at most ``timeout_s`` wall seconds for both (home may stay
    None). InputError when no vehicle is heard."""
    end = time.monotonic() + timeout_s
    vehicle, home = None, None
    while time.monotonic() < end and (vehicle is None or home is None):
        msg = link.recv_match(type=["HEARTBEAT", "HOME_POSITION"], blocking=True,
                              timeout=min(0.5, max(end - time.monotonic(), 0.01)))
        if msg is None:
            continue
        if msg.get_type() == "HEARTBEAT":
            if msg.type != GCS_TYPE and msg.autopilot != INVALID_AUTOPILOT:
                vehicle = (msg.get_srcSystem(), msg.get_srcComponent())
        else:
            home = (msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0)
    if vehicle is None:
        raise InputError(f"no vehicle HEARTBEAT heard on the link within {timeout_s:g} s")
    return vehicle, home


def download_mission(link, vehicle: tuple[int, int], timeout_s: float = 2.0,
                     attempts: int = 3) -> list:
    """The vehicle's mission items with the MAVLink mission protocol (MISSION_REQUEST_LIST,
    MISSION_COUNT, MISSION_REQUEST_INT / MISSION_ITEM_INT per item, MISSION_ACK), each
    request repeated at most ``attempts`` times. InputError when the vehicle does not answer.
    """
    from orange_plan.limits import MAX_MISSION_WAYPOINTS
    from orange_plan.service.mavlink_link import item_from_message

    sysid, compid = vehicle

    def ask(send, kind: str, accept):
        for _ in range(attempts):
            send()
            end = time.monotonic() + timeout_s
            while time.monotonic() < end:
                msg = link.recv_match(type=kind, blocking=True,
                                      timeout=max(end - time.monotonic(), 0.01))
                if msg is not None and accept(msg):
                    return msg
        raise InputError(f"mission download: the vehicle did not answer with {kind} "
                         f"({attempts} attempts of {timeout_s:g} s)")

    count = ask(lambda: link.mav.mission_request_list_send(sysid, compid, 0),
                "MISSION_COUNT", lambda m: True).count
    if count > MAX_MISSION_WAYPOINTS:
        raise InputError(f"mission download: {count} items, more than the "
                         f"{MAX_MISSION_WAYPOINTS} taken")
    items = []
    for seq in range(count):
        it = ask(lambda s=seq: link.mav.mission_request_int_send(sysid, compid, s, 0),
                 "MISSION_ITEM_INT", lambda m, s=seq: m.seq == s)
        items.append(item_from_message(it))
    link.mav.mission_ack_send(sysid, compid, 0, 0)  # MAV_MISSION_ACCEPTED
    return items


def plan_from_items(ctx, home, items):
    """A closed-loop plan of a downloaded mission: its waypoints at their commanded speeds
    (the scenario's cruise speed where none is given). ``home`` = (lat, lon, alt AMSL)."""
    from orange_plan.export.missions_in import mission_from_items

    origin = ctx.world.map.origin
    mission = mission_from_items(home, items, origin, "the vehicle's mission")
    xy = np.array([(w.x_m, w.y_m) for w in mission.waypoints], float)
    if mission.returns_home:
        xy = np.vstack([xy, ctx.world.home_xy_m])
    speed = np.array([w.speed_mps or ctx.cruise_speed_mps for w in mission.waypoints]
                     + [ctx.cruise_speed_mps] * (len(xy) - len(mission.waypoints)), float)
    return route_plan(xy, speed)


def route_plan(xy_m, speed_mps):
    """A route as a plan without planned margins (a closed loop does not read them)."""
    from orange_plan.planning.plan import Plan

    xy = np.asarray(xy_m, float)
    zeros = np.zeros(len(xy))
    return Plan(xy, zeros, np.asarray(speed_mps, float), zeros, zeros, zeros, zeros,
                np.empty((0, 2)), None, {})
