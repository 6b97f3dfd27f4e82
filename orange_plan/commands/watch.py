"""``orange-plan watch``: watch a live vehicle over MAVLink, report the homing margin and the
point of no return, and (with --rtl) send it home in time."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from orange_plan.cli import JsonOpt, app, check_range, handles_errors, out, print_json
from orange_plan.errors import InputError

MAX_RUN_S = 7 * 24 * 3600.0
"""Longest --duration-s taken [s]: a week, beyond any battery flight."""


@app.command("watch")
@handles_errors
def watch_cmd(
    connect: Annotated[str, typer.Option(
        "--connect", help="MAVLink link as pymavlink takes it: udp:HOST:PORT (listen, e.g. "
                          "udp:127.0.0.1:14550), udpout:HOST:PORT, tcp:HOST:PORT, "
                          "tcpin:HOST:PORT or a serial device PATH[,BAUD].")],
    scenario: Annotated[Path, typer.Option(
        "--scenario", help="Scenario TOML: robot, battery, reserve, map (its 'origin' places "
                           "latitude/longitude on the map).")],
    plan: Annotated[Path | None, typer.Option(
        "--plan", help="Plan GeoJSON of 'orange-plan plan' the vehicle flies (its tour).")]
    = None,
    mission_from_vehicle: Annotated[bool, typer.Option(
        "--mission-from-vehicle", help="Download the vehicle's mission (MAVLink mission "
                                       "protocol) instead of --plan.")] = False,
    rtl: Annotated[bool, typer.Option(
        "--rtl", help="Send return-to-launch when the decision is to return home (checked "
                      "by COMMAND_ACK, repeated at most --rtl-attempts times). Without it no "
                      "command is ever sent.")] = False,
    upload: Annotated[bool, typer.Option(
        "--upload", help="When a replan is advised, plan a new tour and upload it to the "
                         "vehicle (mission protocol) after you confirm it on the terminal; "
                         "never on its own.")] = False,
    altitude_m: Annotated[float, typer.Option(
        "--altitude-m", help="Flight altitude above home of an uploaded mission (aerial "
                             "robots) [m].")] = 20.0,
    firmware: Annotated[str, typer.Option(
        "--firmware", help="Autopilot of an uploaded mission: px4 or ardupilot.")] = "px4",
    json_log: Annotated[Path | None, typer.Option(
        "--json-log", help="Write every decision and link event as JSON lines.")] = None,
    rtl_attempts: Annotated[int, typer.Option(
        "--rtl-attempts", help="Most return-to-launch commands sent.")] = 3,
    ack_timeout_s: Annotated[float, typer.Option(
        "--ack-timeout-s", help="Seconds to wait for a COMMAND_ACK before sending again.")]
    = 1.5,
    silent_s: Annotated[float, typer.Option(
        "--silent-s", help="Seconds without a message before the link is said silent.")]
    = 3.0,
    stop_after_silent_s: Annotated[float | None, typer.Option(
        "--stop-after-silent-s", help="Stop once the vehicle, heard before, has been silent "
                                      "this many seconds (default: run until Ctrl-C).")]
    = None,
    duration_s: Annotated[float | None, typer.Option(
        "--duration-s", help="Stop after this many seconds (default: until Ctrl-C).")] = None,
    wait_s: Annotated[float, typer.Option(
        "--wait-s", help="Seconds to wait for the vehicle's HEARTBEAT before a mission "
                         "download.")] = 30.0,
    vertices: Annotated[int, typer.Option(
        "--vertices", min=10, max=20_000,
        help="Roadmap vertices of the way home the decisions cost.")] = 1000,
    as_json: JsonOpt = False,
) -> None:
    """Watch a vehicle over MAVLink: feed its position, battery and wind to a mission
    session and report each decision (margin, probability of getting home, time and distance
    to the point of no return) on the terminal, to the ground station (NAMED_VALUE_FLOAT,
    STATUSTEXT) and in --json-log. With --rtl, send it home when the decision says so."""
    from orange_plan.files import check_output, read_json
    from orange_plan.service.mavlink_link import check_url, open_link
    from orange_plan.service.watch import WatchOptions

    options = WatchOptions(rtl=rtl, upload=upload, altitude_m=altitude_m, firmware=firmware,
                           rtl_attempts=rtl_attempts, ack_timeout_s=ack_timeout_s,
                           silent_s=silent_s)
    for value, name in ((duration_s, "--duration-s"), (stop_after_silent_s,
                                                       "--stop-after-silent-s")):
        if value is not None:
            check_range(value, name, high=MAX_RUN_S)
    check_range(wait_s, "--wait-s", high=MAX_RUN_S)
    if (plan is None) == (not mission_from_vehicle):
        raise InputError("give either --plan PLAN or --mission-from-vehicle (one of them)")
    check_url(connect)
    if json_log is not None:
        check_output(json_log, "--json-log", inputs=[scenario] + ([plan] if plan else []))
    ctx = _context(scenario)
    flown = None if plan is None else _plan_flown(read_json(plan, "--plan"), str(plan))
    link = open_link(connect, system_id=255, component_id=191)  # a companion's ids
    try:
        result = _watch(ctx, flown, link, options, json_log, as_json, wait_s, vertices,
                        duration_s, stop_after_silent_s)
    finally:
        link.close()
    if as_json:
        print_json({"scenario": ctx.scenario.name, **result})


def _context(scenario: Path):
    from orange_plan.context import load_context

    ctx = load_context(scenario)
    if getattr(ctx.world.map, "origin", None) is None:
        raise InputError(f"{ctx.world.map.path}: the map has no 'origin' (the WGS84 point at "
                         "x = y = 0), so the vehicle's latitude/longitude cannot be placed on "
                         'it; add "origin": {"lat_deg": ..., "lon_deg": ..., "alt_m": ...}')
    return ctx


def _plan_flown(data, source: str):
    """The plan's tour, as the vehicle flies it (an exported plan ends its tour at home)."""
    from dataclasses import replace

    from orange_plan.planning.plan import plan_from_geojson

    return replace(plan_from_geojson(data, source), continuation_xy_m=None)


def _watch(ctx, flown, link, options, json_log, as_json, wait_s, vertices, duration_s,
           stop_after_silent_s) -> dict:
    from orange_plan.planning.session import MissionSession
    from orange_plan.service.watch import (
        Watch,
        download_mission,
        json_lines,
        plan_from_items,
        run_watch,
        stdin_lines,
        wait_for_vehicle,
    )

    say = (lambda line: None) if as_json else (lambda line: out.print(line, highlight=False, markup=False,
                                                               soft_wrap=True))
    if flown is None:
        say(f"waiting for the vehicle on {link.address} ...")
        vehicle, home = wait_for_vehicle(link, wait_s)
        if home is None:
            raise InputError("the vehicle sent no HOME_POSITION: its mission cannot be placed")
        flown = plan_from_items(ctx, home, download_mission(link, vehicle))
        say(f"mission downloaded: {len(flown.xy_m)} waypoints")
    # a downloaded mission has no planned margins: the live check alone turns it home
    session = MissionSession(ctx, flown, n_vertices=vertices, closed_loop=not flown.summary)
    session.decision()  # the way-home roadmap is built now, not on the first sample
    write, close = json_lines(json_log) if json_log is not None else (None, lambda: None)
    watch = Watch(session, ctx.world.map.origin, link, options, say=say, log=write)
    if options.upload:
        stdin_lines(watch.answers)
    armed = [w for w, on in (("RTL", options.rtl), ("upload", options.upload)) if on]
    say(f"watching on {link.address} ({' and '.join(armed) + ' armed' if armed else 'reports only'})")

    def silent_too_long() -> bool:
        return (stop_after_silent_s is not None and watch.reader.vehicle is not None
                and watch.silent_for_s() > stop_after_silent_s)

    try:
        run_watch(link, watch, stop_after_s=duration_s, stop_when=silent_too_long)
    except KeyboardInterrupt:
        say("stopped")
    finally:
        close()
    summary = watch.summary()
    if not as_json:
        say(f"{summary['decisions']} decisions; last: {summary['last_action']}; RTL: "
            f"{summary['rtl_state']} ({summary['rtl_attempts']} sent)")
    return summary
