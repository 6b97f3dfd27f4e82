"""``orange-plan export``: a plan as a QGroundControl ``.plan`` or MAVLink waypoint file."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from orange_plan.cli import JsonOpt, app, handles_errors, out, print_json
from orange_plan.errors import InputError


@app.command("export")
@handles_errors
def export_cmd(
    plan: Annotated[Path, typer.Argument(help="Plan GeoJSON written by 'orange-plan plan'.")],
    scenario: Annotated[Path, typer.Option(
        "--scenario", help="Scenario TOML: its map gives the WGS84 'origin' and home, its "
                           "robot kind the vehicle type.")],
    output: Annotated[Path, typer.Option(
        "-o", "--output", help="File to write: .plan (qgc) or .waypoints/.txt/.mission "
                               "(mavlink).")],
    fmt: Annotated[str, typer.Option(
        "--format", help="'qgc' (QGroundControl .plan JSON) or 'mavlink' (QGC WPL 110 text).")]
    = "qgc",
    altitude_m: Annotated[float | None, typer.Option(
        "--altitude-m", help="Flight altitude above home for aerial robots, in metres.")] = None,
    firmware: Annotated[str, typer.Option(
        help="Autopilot firmware written into a .plan: 'px4' or 'ardupilot'.")] = "px4",
    as_json: JsonOpt = False,
) -> None:
    """Write a plan for an autopilot: waypoints in latitude/longitude (the map's origin),
    speed changes as DO_CHANGE_SPEED, the end as return-to-launch."""
    from orange_plan.context import load_context
    from orange_plan.export.autopilot import build_mission, check_extension, write_mission
    from orange_plan.files import check_output
    from orange_plan.sim.route import PLAN_SUFFIXES, load_route

    check_extension(output, fmt)
    check_output(output, "-o", inputs=[plan, scenario])
    if plan.suffix.lower() not in PLAN_SUFFIXES:
        raise InputError(f"{plan}: export takes a plan GeoJSON written by 'orange-plan plan' "
                         f"(a .geojson with the tour), not a {plan.suffix or 'suffix-less'} "
                         "file such as a route or recording CSV")
    route = load_route(plan)
    ctx = load_context(scenario)
    mission = build_mission(ctx.world, ctx.scenario.robot.kind, route.xy_m,
                            route.with_default_speed(ctx.cruise_speed_mps).speed_mps,
                            altitude_m, firmware, source=str(plan))
    write_mission(mission, output, fmt)
    report = {"plan": str(plan), "output": str(output), "format": fmt,
              "tour_vertices": len(route.xy_m), "waypoints": len(mission.waypoints_xy_m),
              "items": len(mission.items) + 1, "home_lat_deg": mission.home_lat_deg,
              "home_lon_deg": mission.home_lon_deg}
    if as_json:
        print_json(report)
        return
    out.print(f"wrote {output}: {report['waypoints']} waypoints from {report['tour_vertices']} "
              f"tour vertices, {report['items']} mission items (home included)")
