"""The watch's link: a reading thread that never leaves the socket unread, the loop that
ticks the watch, the operator's terminal lines, the JSON log, and the mission the vehicle
flies (downloaded with the MAVLink mission protocol).

The link is read by a thread of its own (``run_watch``): a slow decision never leaves the
socket unread; decisions take the queued messages for at most ``DRAIN_S`` at a time.
"""

from __future__ import annotations

import json
import queue
import threading
import time

import numpy as np

from orange_plan.errors import InputError
from orange_plan.service.watch_telemetry import GCS_TYPE, INVALID_AUTOPILOT


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


def run_watch(link, watch, *, stop_after_s: float | None = None,
              stop_when=None, poll_s: float = 0.02, drain_s: float = DRAIN_S) -> None:
    """Read the link in a thread of its own and tick the watch until ``stop_after_s`` wall
    seconds pass or ``stop_when()`` is true (``watch``: a ``service.watch.Watch``).

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
