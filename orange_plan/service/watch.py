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

* ``TelemetryReader`` (``service.watch_telemetry``) turns messages into session samples:
  positions on the map, mission time from the vehicle's time since boot (reboots and
  out-of-order messages handled), the last known battery value where a field is unknown.
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
* The link is read by a thread of its own (``run_watch``, ``service.watch_link``): a slow decision never leaves the
  socket unread; decisions take the queued messages for at most ``DRAIN_S`` at a time. A
  link silent for ``silent_s`` is said once, and its return too.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from orange_plan.errors import InputError, check_range
from orange_plan.export.autopilot import MAX_ALTITUDE_M, check_firmware
from orange_plan.service.mavlink_link import text_bytes
from orange_plan.service.watch_link import (
    DRAIN_S,
    QUEUE_MAX,
    download_mission,
    json_lines,
    plan_from_items,
    route_plan,
    run_watch,
    stdin_lines,
    wait_for_vehicle,
)
from orange_plan.service.watch_telemetry import (
    FIRST_SAMPLE_S,
    INVALID_AUTOPILOT,
    ONBOARD_CONTROLLER,
    REBOOT_BACKSTEP_S,
    TelemetryReader,
)

__all__ = ["DRAIN_S", "FIRST_SAMPLE_S", "QUEUE_MAX", "REBOOT_BACKSTEP_S", "TelemetryReader",
           "Watch", "WatchOptions", "download_mission", "json_lines", "live_line",
           "plan_from_items", "route_plan", "run_watch", "stdin_lines", "wait_for_vehicle"]

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
        check_firmware(self.firmware, "--firmware")
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
