"""``orange-plan fake-vehicle``: a simulated vehicle that flies a plan and speaks MAVLink."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from orange_plan.cli import JsonOpt, ScenarioArg, app, handles_errors, out, print_json
from orange_plan.commands.simulate import SeedOpt, TruthOpt
from orange_plan.errors import InputError

ConnectOpt = Annotated[str, typer.Option(
    "--connect", help="MAVLink link as pymavlink takes it: udpout:HOST:PORT (send to a ground "
                      "station listening there), udp:HOST:PORT (listen), tcp:HOST:PORT, "
                      "tcpin:HOST:PORT or a serial device PATH[,BAUD].")]


@app.command("fake-vehicle")
@handles_errors
def fake_vehicle_cmd(
    scenario: ScenarioArg,
    plan: Annotated[Path | None, typer.Argument(
        help="Plan GeoJSON (its tour) or route CSV (x_m, y_m[, speed_mps]) to fly; not with "
             "--replay.")] = None,
    replay: Annotated[Path | None, typer.Option(
        "--replay", help="Replay a PX4 ULog (.ulg) instead of flying a plan: its positions "
                         "(placed at the map's home) and battery, as recorded.")] = None,
    connect: ConnectOpt = "udpout:127.0.0.1:14550",
    truth: TruthOpt = None,
    speedup: Annotated[float, typer.Option(
        "--speedup", help="Simulated seconds per wall-clock second (1: real time).")] = 1.0,
    rate_hz: Annotated[float, typer.Option(
        "--rate-hz", help="Telemetry rate in simulated time [Hz].")] = 10.0,
    altitude_m: Annotated[float, typer.Option(
        "--altitude-m", help="Flight altitude above home of an aerial vehicle [m].")] = 20.0,
    firmware: Annotated[str, typer.Option(
        "--firmware", help="Which autopilot to sound like: px4 (WIND_COV) or ardupilot "
                           "(WIND).")] = "px4",
    takeoff_after_s: Annotated[float, typer.Option(
        "--takeoff-after-s", help="Wall seconds on the ground before take-off when no ground "
                                  "station speaks first.")] = 5.0,
    linger_s: Annotated[float, typer.Option(
        "--linger-s", help="Wall seconds of heartbeats after landing before it stops.")] = 2.0,
    refuse_rtl: Annotated[int, typer.Option(
        "--refuse-rtl", min=0, max=100,
        help="Answer the first N return-to-launch commands 'temporarily rejected'.")] = 0,
    seed: SeedOpt = 0,
    as_json: JsonOpt = False,
) -> None:
    """Fly a plan in the simulator (in real or accelerated time) and speak MAVLink: position,
    battery, wind, home, heartbeat, mission download and return-to-launch, so that 'watch'
    can be tried with no autopilot. It waits on the ground until a ground station speaks
    (or --takeoff-after-s), flies the plan's tour, and stops after landing or an empty
    battery."""
    from orange_plan.context import load_context
    from orange_plan.service.fake_vehicle import FakeVehicle, VehicleOptions
    from orange_plan.service.mavlink_link import check_url, open_link
    from orange_plan.sim.route import load_route
    from orange_plan.sim.truth import load_truth

    options = VehicleOptions(speedup=speedup, rate_Hz=rate_hz, altitude_m=altitude_m,
                             firmware=firmware, takeoff_after_s=takeoff_after_s,
                             linger_s=linger_s, refuse_rtl=refuse_rtl, seed=seed)
    if (plan is None) == (replay is None):
        raise InputError("give either a PLAN to fly or --replay LOG.ulg (one of them)")
    check_url(connect)
    ctx = load_context(scenario)
    say = (lambda line: None) if as_json else (
        lambda line: out.print(f"vehicle: {line}", highlight=False, markup=False,
                               soft_wrap=True))
    if replay is not None:
        make = _replay(ctx, replay, options, say)
    else:
        route = load_route(plan).with_default_speed(ctx.cruise_speed_mps)
        ctx.world.check_route(route.xy_m, route.source)
        truth_effects = load_truth(truth)

        def make(link):
            return FakeVehicle(ctx, route.xy_m, route.speed_mps, truth_effects, link, options,
                               say=say)
    link = open_link(connect, system_id=1, component_id=1)
    try:
        result = make(link).run()
    finally:
        link.close()
    if as_json:
        print_json({"scenario": ctx.scenario.name, **result})
        return
    if replay is not None:
        out.print(f"replayed {result['samples_sent']} of {result['samples']} samples "
                  f"({result['duration_s']:.1f} s, {result['energy_used_J']:,.0f} J)")
        return
    out.print(f"{result['state']}: {result['energy_used_J']:,.0f} J used of "
              f"{result['energy_available_J']:,.0f} J, {result['energy_left_J']:,.0f} J left, "
              f"{result['distance_from_home_m']:.1f} m from home")


def _replay(ctx, path: Path, options, say):
    """A maker of the ULog replay on a link (the log read and checked first)."""
    from orange_plan.files import require_file
    from orange_plan.service.ulog_replay import UlogReplay
    from orange_plan.telemetry.importers.ulog import read_ulog

    frame = read_ulog(require_file(path, "--replay"))  # a bad log: RecordingError, exit 2
    return lambda link: UlogReplay(ctx, frame, link, options, say=say)
