"""``watch`` and ``fake-vehicle``: telemetry in the map frame, the link faults (each said,
none a crash), the return-to-launch exchange, and both together on 127.0.0.1."""

from __future__ import annotations

import itertools
import json
import math
import socket
import subprocess
import sys
import time
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import REPO, run_cli
from test_json_docs import compare

from orange_plan.export.autopilot import enu_to_geodetic
from orange_plan.planning.session import Decision
from orange_plan.service.mavlink_link import mavlink_module
from orange_plan.service.watch import TelemetryReader, Watch, WatchOptions, run_watch

pytestmark = pytest.mark.timeout(300)

ORIGIN = SimpleNamespace(lat_deg=30.633, lon_deg=-96.479, alt_m=58.0)  # drone_field's
HOME = (30.0, 30.0)
DRONE = REPO / "scenarios" / "ar_drone_wind.toml"
MAV = mavlink_module().mavlink


def wire(msg, system: int = 1, component: int = 1):
    """``msg`` packed by a vehicle (system, component) and decoded, as the link gives it."""
    sender = MAV.MAVLink(None, srcSystem=system, srcComponent=component)
    return MAV.MAVLink(None).decode(bytearray(msg.pack(sender)))


def position(ms: int, x: float, y: float):
    lat, lon, _ = enu_to_geodetic(ORIGIN, x, y)
    return wire(MAV.MAVLink_global_position_int_message(
        ms, round(float(lat) * 1e7), round(float(lon) * 1e7), 78000, 20000, 0, 0, 0, 65535))


def battery(volts_mV: int = 11100, current_cA: int = 500, remaining: int = 90):
    return wire(MAV.MAVLink_battery_status_message(
        0, 0, 0, 32767, [volts_mV] + [65535] * 9, current_cA, -1, -1, remaining))


def heartbeat(system: int = 1):
    return wire(MAV.MAVLink_heartbeat_message(2, 12, 1, 0, 4, 3), system=system)


def ack(result: int):
    return wire(MAV.MAVLink_command_ack_message(20, result, 0, 0, 255, 191))


class Clock:
    """A wall clock the test moves."""

    def __init__(self):
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


class Sent:
    """A link's ``mav``: records every message sent."""

    def __init__(self):
        self.calls = []

    def __getattr__(self, name):
        return lambda *args: self.calls.append((name, args))

    def names(self) -> list[str]:
        return [name for name, _ in self.calls]


class StubSession:
    """A session that takes any batch and answers ``action`` with the given margin."""

    def __init__(self, action="continue", margin=1000.0):
        self.ctx = SimpleNamespace(world=SimpleNamespace(home_xy_m=HOME))
        self.action, self.margin, self.fed = action, margin, []

    def feed(self, rows):
        self.fed.append(list(rows))
        last = rows[-1]
        return Decision(self.action, "stub", (last["x_m"], last["y_m"]), 0.0, last["t_s"],
                        10.0, 5.0, self.margin, 0.99, 100.0, 0.0, 5000.0)


def make_watch(session=None, **options):
    clock, lines, log = Clock(), [], []
    link = SimpleNamespace(mav=Sent())
    watch = Watch(session or StubSession(), ORIGIN, link, WatchOptions(**options),
                  say=lines.append, log=log.append, clock=clock)
    return watch, clock, lines, log, link.mav


def feed(watch, messages):
    for msg in messages:
        watch.take(msg)
    return watch.tick()


# --- telemetry ---------------------------------------------------------------------------


def test_positions_become_map_frame_samples_with_the_battery_power():
    samples = []
    reader = TelemetryReader(ORIGIN, HOME, lambda kind, text: None)
    for msg in (battery(), position(5000, 120.0, 80.0), position(5100, 121.0, 80.5)):
        reader.take(msg)
    samples, _ = reader.pop()
    assert len(samples) == 2
    assert samples[0]["x_m"] == pytest.approx(120.0, abs=0.02)
    assert samples[1]["y_m"] == pytest.approx(80.5, abs=0.02)
    assert samples[1]["t_s"] - samples[0]["t_s"] == pytest.approx(0.1)
    assert samples[0]["voltage_V"] * samples[0]["current_A"] == pytest.approx(55.5)
    assert samples[0]["soc"] == pytest.approx(0.9)


def test_wind_cov_and_wind_give_speed_and_where_it_blows_from():
    reader = TelemetryReader(ORIGIN, HOME, lambda kind, text: None)
    # PX4: the air moves towards the north-east at 3 m/s -> from 225 deg
    reader.take(wire(MAV.MAVLink_wind_cov_message(0, 3 / math.sqrt(2), 3 / math.sqrt(2), 0,
                                                  0, 0, 0, 0, 0)))
    assert reader.wind == pytest.approx((3.0, 225.0))
    reader.take(wire(MAV.MAVLink_wind_message(250.0, 5.0, 0.0)))  # ArduPilot
    assert reader.wind == pytest.approx((5.0, 250.0))


def test_local_position_is_placed_from_home_position_when_no_global_one_comes():
    reader = TelemetryReader(ORIGIN, HOME, lambda kind, text: None)
    reader.take(battery())
    reader.take(wire(MAV.MAVLink_home_position_message(0, 0, 0, 2.0, -1.0, 0.0, [1, 0, 0, 0],
                                                       0, 0, 0)))
    reader.take(wire(MAV.MAVLink_local_position_ned_message(1000, 12.0, 9.0, -20, 0, 0, 0)))
    (row,), _ = reader.pop()
    assert (row["x_m"], row["y_m"]) == pytest.approx((HOME[0] + 10.0, HOME[1] + 10.0))


# --- link faults -------------------------------------------------------------------------


def test_duplicate_and_out_of_order_positions_are_dropped_and_said():
    watch, _, lines, log, _ = make_watch()
    feed(watch, [battery(), position(5000, 40, 40), position(5100, 41, 40)])
    feed(watch, [position(5100, 41, 40), position(5050, 40.5, 40), position(5200, 42, 40)])
    fed = watch.session.fed
    times = [r["t_s"] for batch in fed for r in batch]
    assert times == sorted(set(times)) and len(times) == 3
    assert watch.reader.dropped == 2
    assert any("out_of_order" in line for line in lines)
    assert any(r.get("event") == "out_of_order" for r in log)


def test_a_reboot_restarts_time_since_boot_and_mission_time_goes_on():
    watch, _, lines, _log, _ = make_watch()
    feed(watch, [battery(), position(600_000, 40, 40), position(600_100, 41, 40)])
    feed(watch, [heartbeat(), position(1_200, 41.5, 40), position(1_300, 42, 40)])
    times = [r["t_s"] for batch in watch.session.fed for r in batch]
    assert all(b > a for a, b in itertools.pairwise(times))
    assert watch.reader.reboots == 1
    assert any("rebooted" in line for line in lines)
    assert watch.reader.dropped == 0


def test_battery_fields_marked_unknown_keep_the_last_known_values():
    watch, _, lines, _, _ = make_watch()
    feed(watch, [battery(11100, 500, 90), position(5000, 40, 40)])
    d = feed(watch, [battery(65535, -1, -1), position(5100, 41, 40)])
    assert d is not None
    row = watch.session.fed[-1][-1]
    assert (row["voltage_V"], row["current_A"], row["soc"]) == (11.1, 5.0, 0.9)
    assert any("without voltage, current, remaining" in line for line in lines)


def test_a_battery_never_known_feeds_nothing_and_says_why():
    watch, _, lines, _, _ = make_watch()
    assert feed(watch, [battery(65535, -1, -1), position(5000, 40, 40)]) is None
    assert watch.session.fed == []
    assert any("no battery voltage and current yet" in line for line in lines)


def test_a_silent_link_is_said_once_and_so_is_its_return():
    watch, clock, lines, log, _ = make_watch(silent_s=3.0)
    feed(watch, [battery(), position(5000, 40, 40)])
    for _ in range(5):
        clock.now += 1.0
        watch.tick()
    assert sum("link_silent" in line for line in lines) == 1
    feed(watch, [position(5100, 41, 40)])
    assert sum("link_back" in line for line in lines) == 1
    assert [r["event"] for r in log if r["kind"] == "event"][-1] == "link_back"


def test_a_refused_batch_is_said_and_the_watch_goes_on():
    from orange_plan.errors import InputError

    class Refusing(StubSession):
        def feed(self, rows):
            raise InputError("samples: row 0 lies off the map")

    watch, _, lines, _, _ = make_watch(Refusing())
    assert feed(watch, [battery(), position(5000, 40, 40)]) is None
    assert any("telemetry_refused" in line for line in lines)


def test_the_watch_does_not_block_on_a_link_that_says_nothing():
    watch, *_ = make_watch()
    silent = SimpleNamespace(recv_match=lambda blocking=False, timeout=None: None)
    start = time.monotonic()
    run_watch(silent, watch, stop_after_s=0.2)
    assert time.monotonic() - start < 1.0


def test_a_slow_decision_does_not_stop_the_link_being_read():
    class Slow(StubSession):
        def feed(self, rows):
            time.sleep(0.3)
            return super().feed(rows)

    watch, *_ = make_watch(Slow())
    queued = [battery()] + [position(5000 + 100 * i, 40 + i * 0.1, 40) for i in range(200)]
    start, read_at = time.monotonic(), []

    def recv_match(blocking=False, timeout=None):
        """The i-th message arrives 2 ms after the one before."""
        due = start + 0.002 * len(read_at)
        if not queued or time.monotonic() < due:
            if blocking:
                time.sleep(min(timeout or 0, max(due - time.monotonic(), 0)))
            return None
        read_at.append(time.monotonic())
        return queued.pop(0)

    run_watch(SimpleNamespace(recv_match=recv_match), watch, stop_after_s=1.5)
    assert len(read_at) == 201
    gaps = [b - a for a, b in itertools.pairwise(read_at)]
    assert max(gaps) < 0.15  # the link was read while each decision took 0.3 s


# --- reports and return to launch ----------------------------------------------------------


def test_each_decision_is_reported_to_the_ground_station_and_the_log():
    watch, _, lines, log, sent = make_watch()
    feed(watch, [heartbeat(), battery(), position(5000, 40, 40)])
    assert sent.names().count("named_value_float_send") == 4
    assert "statustext_send" in sent.names()
    assert "command_long_send" not in sent.names()
    record = next(r for r in log if r["kind"] == "decision")
    assert record["action"] == "continue" and record["samples"] == 1
    assert any(line.startswith("t ") and "margin" in line and "P(home)" in line
               for line in lines)


def test_without_rtl_a_return_home_decision_sends_no_command():
    watch, _, _, _, sent = make_watch(StubSession("return_home", -50.0), rtl=False)
    feed(watch, [heartbeat(), battery(), position(5000, 40, 40)])
    assert watch.last_decision.action == "return_home"
    assert not [n for n in sent.names() if n.startswith(("command", "mission"))]


def test_rtl_is_sent_once_and_not_again_after_it_is_accepted():
    watch, _, _, _, sent = make_watch(StubSession("return_home", -50.0), rtl=True)
    feed(watch, [heartbeat(), battery(), position(5000, 40, 40)])
    feed(watch, [ack(0), position(5100, 41, 40)])
    feed(watch, [position(5200, 42, 40)])
    commands = [args for name, args in sent.calls if name == "command_long_send"]
    assert len(commands) == 1 and commands[0][:3] == (1, 1, 20)
    assert watch.rtl.state == "accepted"


def test_rtl_is_repeated_when_refused_or_unanswered_and_at_most_the_attempts():
    watch, clock, lines, _, sent = make_watch(StubSession("return_home", -50.0), rtl=True,
                                              rtl_attempts=3, ack_timeout_s=1.5)
    feed(watch, [heartbeat(), battery(), position(5000, 40, 40)])
    feed(watch, [ack(1)])  # temporarily rejected: sent again at once
    clock.now += 2.0  # no answer within the timeout: sent a third time
    watch.tick()
    clock.now += 2.0  # no answer again: given up
    watch.tick()
    assert sent.names().count("command_long_send") == 3
    assert watch.rtl.state == "failed"
    assert any("rtl_failed" in line for line in lines)
    clock.now += 10.0
    feed(watch, [position(5100, 41, 40)])
    assert sent.names().count("command_long_send") == 3


def test_rtl_waits_for_the_vehicle_heartbeat():
    watch, _, _lines, _, sent = make_watch(StubSession("return_home", -50.0), rtl=True)
    feed(watch, [battery(), position(5000, 40, 40)])
    assert "command_long_send" not in sent.names()
    feed(watch, [heartbeat(), position(5100, 41, 40)])
    assert sent.names().count("command_long_send") == 1


# --- the command line ----------------------------------------------------------------------


@pytest.mark.parametrize("url", ["udp:127.0.0.1", "udp:127.0.0.1:99999", "http://x:80",
                                 "/dev/no-such-port,57600", "udpout:host:port"])
def test_a_bad_link_url_is_one_line_and_exit_2(url, tmp_path):
    code, _, err = run_cli("watch", "--connect", url, "--scenario", DRONE,
                           "--mission-from-vehicle")
    assert code == 2 and err.count("\n") == 1 and "--connect" in err


def test_watch_needs_exactly_one_of_plan_and_mission_from_vehicle(tmp_path):
    code, _, err = run_cli("watch", "--connect", "udp:127.0.0.1:14550", "--scenario", DRONE)
    assert code == 2 and "--mission-from-vehicle" in err


def test_a_map_without_origin_is_one_line_and_exit_2(tmp_path):
    from planning_worlds import write_world

    scenario = write_world(tmp_path)
    code, _, err = run_cli("watch", "--connect", "udp:127.0.0.1:14550", "--scenario",
                           scenario, "--mission-from-vehicle")
    assert code == 2 and "origin" in err and err.count("\n") == 1
    route = tmp_path / "r.csv"
    route.write_text("x_m,y_m\n2,2\n10,2\n2,2\n")
    code, _, err = run_cli("fake-vehicle", scenario, route, "--connect",
                           "udpout:127.0.0.1:14550")
    assert code == 2 and "origin" in err and err.count("\n") == 1


# --- end to end on 127.0.0.1 -----------------------------------------------------------------

HEAVY = "[payload]\nextra_kg = 0.126\nfrom_s = 0.0\n"
"""30 % of the AR.Drone's 0.42 kg more than the scenario says."""


def lawnmower_csv(path):
    """Twelve lanes over the drone field, west of the copse and south of the tree line: the
    scenario's model flies it home with 4.5 kJ left, more than its 3.7 kJ reserve."""
    rows, up = ["x_m,y_m"], True
    for i in range(12):
        ys = (30, 170) if up else (170, 30)
        rows += [f"{30 + 16 * i},{y}" for y in ys]
        up = not up
    path.write_text("\n".join([*rows, "30,30"]) + "\n")
    return path


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cli(*args) -> list[str]:
    return [sys.executable, "-m", "orange_plan.cli", *map(str, args)]


def fly(tmp_path, *, watch_args=None, name="flight", speedup=40):
    """fake-vehicle (accelerated, truth 30 % heavier) and, if given, watch on loopback."""
    route, truth = lawnmower_csv(tmp_path / "lanes.csv"), tmp_path / "heavy.toml"
    truth.write_text(HEAVY)
    port = free_udp_port()
    vehicle = subprocess.Popen(
        cli("fake-vehicle", DRONE, route, "--connect", f"udpout:127.0.0.1:{port}", "--truth",
            truth, "--speedup", speedup, "--takeoff-after-s", 90 if watch_args else 0,
            "--linger-s", 1, "--refuse-rtl", 1, "--json"),
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    log = tmp_path / f"{name}.jsonl"
    watched = None
    if watch_args is not None:
        watched = subprocess.run(
            cli("watch", "--connect", f"udp:127.0.0.1:{port}", "--scenario", DRONE,
                "--mission-from-vehicle", "--json-log", log, "--stop-after-silent-s", 2,
                "--duration-s", 200, "--json", *watch_args),
            cwd=REPO, capture_output=True, text=True, timeout=260)
        assert watched.returncode == 0, watched.stderr
    out, err = vehicle.communicate(timeout=260)
    assert vehicle.returncode == 0, err
    records = [json.loads(line) for line in log.read_text().splitlines()] if watched else []
    return json.loads(out), (json.loads(watched.stdout) if watched else None), records


def test_watch_sends_a_heavy_vehicle_home_in_time_and_without_it_the_vehicle_strands(
        tmp_path):
    alone, _, _ = fly(tmp_path, name="alone")
    assert alone["stranded"] and alone["state"] == "stranded"
    assert alone["distance_from_home_m"] > 50 and alone["rtl_commands"] == 0

    vehicle, watch, records = fly(tmp_path, watch_args=["--rtl"], name="watched")
    events = [r["event"] for r in records if r["kind"] == "event"]
    # the vehicle refused the first RTL: the watch sent it again and it was accepted
    assert events.count("rtl_sent") == 2 and "rtl_rejected" in events
    assert "rtl_accepted" in events and watch["rtl_state"] == "accepted"
    assert vehicle["mission_downloads"] == 1 and vehicle["rtl_commands"] == 2
    assert vehicle["state"] == "landed" and not vehicle["stranded"]
    assert vehicle["distance_from_home_m"] < 1.0 and vehicle["energy_left_J"] > 0
    decisions = [r for r in records if r["kind"] == "decision"]
    assert decisions[-1]["energy_used_J"] == pytest.approx(vehicle["energy_used_J"], rel=0.05)
    # every key printed is in docs/json.md
    compare("watch", watch)
    compare("fake-vehicle", vehicle)
    for record in records:
        compare("watch --json-log", record)


def test_bench_watch_measures_how_far_decisions_lag_the_telemetry():
    code, out, err = run_cli("bench", "watch", "--duration-s", 4, "--json")
    assert code == 0, err
    result = json.loads(out)
    assert result["decisions"] > 10 and result["rate_Hz"] == 10.0
    assert 0 < result["lag_median_s"] <= result["lag_p95_s"] <= result["lag_max_s"]
    compare("bench watch", result)


@pytest.mark.slow
def test_without_rtl_the_watch_reports_but_never_commands(tmp_path):
    vehicle, watch, records = fly(tmp_path, watch_args=[], name="reports")
    assert vehicle["rtl_commands"] == 0 and vehicle["stranded"]
    assert watch["rtl_attempts"] == 0
    assert any(r["kind"] == "decision" and r["action"] == "return_home" for r in records)


def test_a_px4_log_replayed_as_mavlink_is_watched_with_its_unknown_current_said(tmp_path):
    from logbuilders import VOLTAGE_V, write_ulog

    log_file = write_ulog(tmp_path / "flight.ulg", current_unknown_at=5)
    port = free_udp_port()
    replay = subprocess.Popen(
        cli("fake-vehicle", DRONE, "--replay", log_file, "--connect",
            f"udpout:127.0.0.1:{port}", "--speedup", 4, "--takeoff-after-s", 90,
            "--linger-s", 1, "--json"),
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    log = tmp_path / "replay.jsonl"
    watched = subprocess.run(
        cli("watch", "--connect", f"udp:127.0.0.1:{port}", "--scenario", DRONE,
            "--mission-from-vehicle", "--rtl", "--json-log", log, "--stop-after-silent-s", 2,
            "--duration-s", 120, "--json"), cwd=REPO, capture_output=True, text=True,
        timeout=180)
    out, err = replay.communicate(timeout=60)
    assert watched.returncode == 0 and replay.returncode == 0, (watched.stderr, err)
    replayed, watch = json.loads(out), json.loads(watched.stdout)
    assert replayed["state"] == "replayed" and replayed["samples_sent"] == replayed["samples"]
    # every sample reached the watch: the energy it measured is the log's
    assert watch["energy_used_J"] == pytest.approx(replayed["energy_used_J"], rel=0.02)
    assert replayed["energy_used_J"] == pytest.approx(VOLTAGE_V * 2.0 * 10.0, rel=0.02)
    records = [json.loads(line) for line in log.read_text().splitlines()]
    assert any(r.get("event") == "battery_current" for r in records)
    compare("fake-vehicle", replayed)


# --- a replanned mission uploaded on the operator's word ------------------------------------


@pytest.fixture(scope="module")
def drone():
    from orange_plan.context import load_context

    return load_context(DRONE)


class ReplanningSession(StubSession):
    """Advises a replan; its copy (``from_state``) replans a short tour."""

    def __init__(self, ctx):
        super().__init__("replan")
        self.ctx, self.adopted = ctx, []

    def state_dict(self):
        return {}

    @classmethod
    def from_state(cls, ctx, state):
        return cls(ctx)

    def replan(self):
        from orange_plan.service.watch import route_plan

        return route_plan([[30, 30], [60, 30], [60, 60], [30, 30]], [5.0] * 4)

    def adopt_stored_plan(self, geojson):
        self.adopted.append(geojson)


def replanned(drone, answer: str):
    watch, clock, lines, log, sent = make_watch(ReplanningSession(drone), upload=True)
    feed(watch, [heartbeat(), battery(), position(5000, 40, 40)])
    watch.up.worker.join(timeout=30)
    watch.tick()
    assert watch.up.state == "asking" and any("type y" in line for line in lines)
    watch.answers.put(answer)
    watch.tick()
    return watch, clock, lines, log, sent


def test_a_replan_is_uploaded_only_after_the_operator_says_yes_and_adopted_on_ack(drone):
    watch, _, _, log, sent = replanned(drone, "y\n")
    (count,) = [args for name, args in sent.calls if name == "mission_count_send"]
    n = count[2]
    for seq in range(n):
        watch.take(wire(MAV.MAVLink_mission_request_int_message(255, 191, seq, 0)))
    items = [args for name, args in sent.calls if name == "mission_item_int_send"]
    assert [args[2] for args in items] == list(range(n))
    assert watch.session.adopted == []  # not before the vehicle accepts
    watch.take(wire(MAV.MAVLink_mission_ack_message(255, 191, 0, 0)))
    assert len(watch.session.adopted) == 1
    assert [r["event"] for r in log if r["kind"] == "event"][-1] == "upload_accepted"


def test_a_replan_the_operator_declines_is_never_sent(drone):
    watch, _, _, log, sent = replanned(drone, "n\n")
    assert not [n for n in sent.names() if n.startswith("mission")]
    assert watch.session.adopted == [] and watch.up.state == "idle"
    assert any(r.get("event") == "upload_declined" for r in log)


def test_an_upload_the_vehicle_does_not_answer_is_repeated_then_given_up(drone):
    watch, clock, _, log, sent = replanned(drone, "yes\n")
    for _ in range(3):
        clock.now += 2.0
        watch.tick()
    assert sent.names().count("mission_count_send") == 3
    assert watch.session.adopted == [] and watch.up.state == "idle"
    assert any(r.get("event") == "upload_failed" for r in log)


def test_without_upload_a_replan_decision_plans_nothing(drone):
    watch, _, _, _, sent = make_watch(ReplanningSession(drone))
    feed(watch, [heartbeat(), battery(), position(5000, 40, 40)])
    assert watch.up.state == "idle" and watch.up.worker is None
    assert not [n for n in sent.names() if n.startswith("mission")]


def test_the_fake_vehicle_flies_an_uploaded_mission_from_where_it_is(drone):
    from orange_plan.export.autopilot import build_mission
    from orange_plan.service.fake_vehicle import FakeVehicle, VehicleOptions
    from orange_plan.service.mavlink_link import send_mission_item

    sent = Sent()
    link = SimpleNamespace(mav=sent, recv_match=lambda **kw: None)
    lanes = [[30, 30], [30, 170], [46, 170], [46, 30], [30, 30]]
    vehicle = FakeVehicle(drone, lanes, [5.0] * 5, None, link, VehicleOptions(speedup=100),
                          say=lambda line: None)
    vehicle.state = "flying"
    vehicle.segment = vehicle._simulate(lanes, [5.0] * 5, 0.0, 0.0)
    vehicle.segment.k = 100  # 10 s into the flight
    new = build_mission(drone.world, "aerial", [[30, 60], [100, 60], [100, 100], [30, 30]],
                        [5.0] * 4, 20.0)
    vehicle._on_mission_count(wire(MAV.MAVLink_mission_count_message(1, 1, len(new.items),
                                                                      0), system=255))
    for seq, item in enumerate(new.items):  # as the watch sends them (send_mission_item)
        items = Sent()
        send_mission_item(items, (1, 1), seq, item)
        (args,) = [a for _, a in items.calls]
        vehicle._on_mission_item_int(wire(MAV.MAVLink_mission_item_int_message(*args),
                                          system=255))
    ((ack),) = [args for name, args in sent.calls if name == "mission_ack_send"]
    assert ack[2] == 0  # accepted
    assert vehicle.log.uploads == 1 and vehicle.state == "flying"
    path = vehicle.segment.frame[["x_m", "y_m"]].to_numpy(float)
    assert path[0] == pytest.approx([30, 30 + 0.5 * 10 * 5], abs=30)  # from where it was
    assert path[-1] == pytest.approx([30, 30], abs=0.5)


@pytest.mark.slow
def test_an_upload_confirmed_on_the_terminal_is_flown_by_the_vehicle(tmp_path, drone):
    """Loopback: a heavier vehicle than its plan file's, so a replan is advised; the
    operator types y."""
    from orange_plan.service.watch import route_plan

    lanes, truth = lawnmower_csv(tmp_path / "lanes.csv"), tmp_path / "heavy.toml"
    truth.write_text(HEAVY)
    xy = np.loadtxt(lanes, delimiter=",", skiprows=1)
    plan = route_plan(xy, np.full(len(xy), 5.0))
    plan.summary["planned_by"] = "test"  # a plan file: flown open loop, its margins checked
    plan_file = tmp_path / "plan.geojson"
    plan_file.write_text(json.dumps(plan.to_geojson()))
    port = free_udp_port()
    vehicle = subprocess.Popen(
        cli("fake-vehicle", DRONE, lanes, "--connect", f"udpout:127.0.0.1:{port}",
            "--truth", truth, "--speedup", 5, "--takeoff-after-s", 90, "--linger-s", 1, "--json"),
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    log = tmp_path / "upload.jsonl"
    watch = subprocess.Popen(
        cli("watch", "--connect", f"udp:127.0.0.1:{port}", "--scenario", DRONE, "--plan",
            plan_file, "--upload", "--json-log", log, "--stop-after-silent-s", 2,
            "--duration-s", 240, "--vertices", 300),
        cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True)
    deadline = time.monotonic() + 200
    while time.monotonic() < deadline and not (log.exists() and "upload_asked" in
                                               log.read_text()):
        time.sleep(0.5)
    assert watch.poll() is None, "the watch ended before it offered an upload"
    watch.stdin.write("y\n")
    watch.stdin.flush()
    _, werr = watch.communicate(timeout=260)
    out, err = vehicle.communicate(timeout=60)
    assert watch.returncode == 0 and vehicle.returncode == 0, (werr, err)
    events = [json.loads(line).get("event") for line in log.read_text().splitlines()]
    assert "upload_sent" in events and "upload_accepted" in events
    assert json.loads(out)["mission_uploads"] == 1
