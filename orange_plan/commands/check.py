"""``orange-plan check``: does a mission (QGroundControl, MAVLink, route CSV, GeoJSON or a plan)
fit the battery, leg by leg, with the way home from every waypoint?"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from orange_plan.cli import JsonOpt, app, check_range, handles_errors, out, print_json, warn
from orange_plan.errors import InputError

MAX_WIND_MPS = 100.0
"""Fastest wind ``--wind`` takes [m/s]: beyond any storm a battery robot flies in, so a larger
number is a slip of units."""


def parse_wind(text: str) -> tuple[float, float]:
    """``"SPEED@FROM_DEG"`` -> (speed [m/s], from [deg]); InputError naming ``--wind``."""
    parts = str(text).split("@")
    try:
        speed, from_deg = (float(p) for p in parts)
    except ValueError:
        raise InputError(f"--wind must be SPEED@FROM_DEG (m/s @ degrees the wind blows from, "
                         f"e.g. 6@270), got {text!r}") from None
    if not (math.isfinite(speed) and math.isfinite(from_deg)):
        raise InputError(f"--wind must be finite, got {text!r}")
    check_range(speed, "--wind speed", high=MAX_WIND_MPS, low_open=False)
    return speed, from_deg % 360.0


@app.command("check")
@handles_errors
def check_cmd(
    mission: Annotated[Path, typer.Argument(
        help="Mission: a QGroundControl .plan, a MAVLink waypoint file (QGC WPL 110), a route "
             ".csv (x_m, y_m[, z_m, speed_mps, stay_s, corner_radius_m]), a GeoJSON "
             "LineString (longitude/latitude) or a plan GeoJSON of 'orange-plan plan'.")],
    scenario: Annotated[Path, typer.Option(
        "--scenario", help="Scenario TOML: robot, battery, reserve, map (its 'origin' places "
                           "latitude/longitude).")],
    wind: Annotated[str | None, typer.Option(
        "--wind", help="Wind SPEED@FROM_DEG (m/s, degrees it blows from) instead of the "
                       "scenario's; also reports the costliest direction.")] = None,
    acceptance_radius_m: Annotated[float, typer.Option(
        "--acceptance-radius-m", help="Autopilot acceptance radius for MAVLink waypoints that "
                                      "give none [m]: the turn starts this far before the "
                                      "waypoint.")] = 2.0,
    corners_as_planned: Annotated[bool, typer.Option(
        "--corners-as-planned", help="Pass every waypoint without slowing or stopping (holds "
                                     "still stop), as 'orange-plan plan' models a tour.")]
    = False,
    png: Annotated[Path | None, typer.Option(
        "--png", help="Write a PNG: the route coloured by homing margin, the point of no "
                      "return, margin against distance.")] = None,
    as_json: JsonOpt = False,
) -> None:
    """Check a mission against the battery: energy and time per leg (with their predictive
    standard deviation), the way home and homing margin at every waypoint, the point of no
    return and a verdict."""
    from orange_plan.context import load_context
    from orange_plan.export.missions_in import read_mission
    from orange_plan.physics.wind import wind_xy_mps
    from orange_plan.planning.mission_check import check_mission

    wind_xy = None if wind is None else wind_xy_mps(*parse_wind(wind))
    check_range(acceptance_radius_m, "--acceptance-radius-m", low_open=False)
    if png is not None:
        from orange_plan.paths import check_output

        check_output(png, "--png", [".png"], inputs=[mission, scenario])
    ctx = load_context(scenario)
    origin = getattr(ctx.world.map, "origin", None)
    read = read_mission(mission, origin, acceptance_radius_m)
    if corners_as_planned:
        read = read.turning_without_slowing()
    in_map = origin is not None or mission.suffix.lower() == ".csv" or _is_plan(mission)
    result = check_mission(read, ctx, wind=wind_xy, worst_wind=wind is not None,
                           in_map_frame=in_map)
    if png is not None:
        from orange_plan.viz.check_plot import plot_check

        plot_check(ctx.world if in_map else None, read, result, png,
                   f"{ctx.scenario.name}: {mission.name}, {result.verdict.replace('_', ' ')}")
    report = {"mission": str(mission), "scenario": ctx.scenario.name,
              "in_map_frame": in_map, **result.as_dict()}
    for line in result.warnings:
        warn(line)
    if as_json:
        print_json(report)
        return
    _print_report(report, png)


def _is_plan(path: Path) -> bool:
    """A plan GeoJSON (map frame) rather than a longitude/latitude LineString."""
    if path.suffix.lower() not in (".geojson", ".json"):
        return False
    from orange_plan.paths import read_json

    data = read_json(path, "mission GeoJSON")
    return isinstance(data, dict) and any(
        isinstance(f, dict) and (f.get("properties") or {}).get("kind") == "tour"
        for f in data.get("features") or [])


def _kj(value) -> str:
    return f"{value / 1e3:,.2f}"


VERDICT_TEXT = {"fits": "[green]fits[/] with the reserve",
                "fits_without_reserve": "[yellow]fits only without the reserve[/]",
                "does_not_fit": "[red]does not fit[/]"}


def _print_report(report: dict, png) -> None:
    table = Table(show_header=True, header_style="bold")
    for col in ("leg", "from", "to", "length m", "climb m", "speed m/s", "kJ", "sd kJ", "s",
                "used kJ", "home kJ", "margin kJ"):
        table.add_column(col, justify="left" if col == "leg" else "right")
    for leg in report["legs"]:
        table.add_row(leg["kind"], str(leg["from"]), str(leg["to"]), f"{leg['length_m']:.1f}",
                      f"{leg['climb_m']:.1f}", f"{leg['speed_mps']:.2f}", _kj(leg["energy_J"]),
                      _kj(leg["energy_sd_J"]), f"{leg['duration_s']:.1f}",
                      _kj(leg["energy_used_J"]), _kj(leg["energy_to_home_J"]),
                      _kj(leg["margin_J"]) if leg["margin_J"] >= 0
                      else f"[red]{_kj(leg['margin_J'])}[/]")
    out.print(table)
    out.print(f"{report['scenario']}: {report['mission']}: {_kj(report['energy_J'])} +- "
              f"{_kj(report['energy_sd_J'])} kJ in {report['duration_s']:,.0f} s of "
              f"{_kj(report['energy_available_J'])} kJ available, reserve "
              f"{_kj(report['reserve_J'])} kJ ({report['reserve_rule']})")
    verdict = VERDICT_TEXT[report["verdict"]]
    if report["first_failing_waypoint"] is not None:
        verdict += f" (first failing at waypoint {report['first_failing_waypoint']})"
    out.print(f"verdict: {verdict}")
    pnr = report["point_of_no_return"]
    if pnr is None:
        out.print("point of no return: the start (no margin before the take-off)")
    elif report["verdict"] == "fits":
        out.print(f"point of no return: none, the margin holds to the end "
                  f"({pnr['distance_m']:,.1f} m)")
    else:
        out.print(f"point of no return: {pnr['distance_m']:,.1f} m along the route, on the "
                  f"leg leaving waypoint {pnr['waypoint']}")
    if report["worst_wind"] is not None:
        w = report["worst_wind"]
        out.print(f"worst wind direction: from {w['from_deg']:g} deg, "
                  f"{_kj(w['energy_J'])} kJ")
    if not report["in_map_frame"]:
        out.print("the map has no 'origin': the mission was checked in a local frame at its "
                  "home, on flat default ground")
    if png is not None:
        out.print(f"wrote {png}")
