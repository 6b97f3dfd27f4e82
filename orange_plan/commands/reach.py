"""``orange-plan reach``: which goals can be visited with the robot still getting home."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from orange_plan.cli import (
    MAX_TIME_S,
    JsonOpt,
    ScenarioArg,
    app,
    check_range,
    handles_errors,
    out,
    parse_xy,
    print_json,
    progress_console,
    warn,
)
from orange_plan.limits import MAX_ROADMAP_VERTICES, MIN_ROADMAP_VERTICES
from orange_plan.progress import stages


@app.command("reach")
@handles_errors
def reach_cmd(
    scenario: ScenarioArg,
    from_xy: Annotated[str | None, typer.Option(
        "--from", help="Robot position X,Y in metres (default: home).")] = None,
    energy_used_J: Annotated[float, typer.Option(
        "--energy-used-J", help="Battery energy already used [J].")] = 0.0,
    time_used_s: Annotated[float, typer.Option(
        "--time-used-s", help="Mission time already spent [s] (counts against "
        "mission.time_limit_s).")] = 0.0,
    goals: Annotated[Path | None, typer.Option(
        "--goals", help="CSV with columns x_m, y_m (optional name).")] = None,
    png: Annotated[Path | None, typer.Option(
        "--png", help="Write a PNG of the feasible region (colour = margin).")] = None,
    vertices: Annotated[int, typer.Option(
        help=f"Roadmap vertices ({MIN_ROADMAP_VERTICES} to {MAX_ROADMAP_VERTICES:,}).")] = 5000,
    seed: Annotated[int, typer.Option(help="Roadmap random seed.")] = 0,
    as_json: JsonOpt = False,
) -> None:
    """Which goals can be visited and the robot still get home with its reserve."""
    from orange_plan.context import load_context
    from orange_plan.planning.goals import load_goals
    from orange_plan.planning.reach import home_status, prepare_reach, query_goals, query_points

    check_range(time_used_s, "--time-used-s", high=MAX_TIME_S, low_open=False)
    start = parse_xy(from_xy, "--from") if from_xy is not None else None
    goal_set = load_goals(goals) if goals is not None else None
    if png is not None:
        from orange_plan.files import check_output

        check_output(png, "--png", [".png"], inputs=[scenario, goals])
    with stages(progress_console(as_json)) as step:
        step("loading scenario")
        ctx = load_context(scenario)
        step(f"building the energy roadmap ({vertices} vertices)")
        reach = prepare_reach(ctx, start, energy_used_J, n_vertices=vertices, seed=seed,
                              time_used_s=time_used_s)
        home = home_status(reach)
        step("querying goals")
        results = [] if goal_set is None else query_goals(reach, goal_set.xy_m, goal_set.names)
        if png is not None:
            from orange_plan.viz.reach_plot import field_grid, plot_reach

            step("drawing the margin field")
            xs, ys, points = field_grid(ctx.world)
            field = query_points(reach, points)
            title = (f"{ctx.scenario.name}: reach at {reach.exact.speed_mps:.2f} m/s; energy used "
                     f"{energy_used_J / 1e3:,.1f} of {reach.energy_available_J / 1e3:,.1f} kJ, "
                     f"reserve {reach.reserve.describe()}")
            plot_reach(reach, field, xs, ys, results, png, title)
    report = {
        "home_xy_m": list(reach.home_xy_m),
        "from_xy_m": list(reach.start_xy_m),
        "energy_available_J": reach.energy_available_J,
        "energy_used_J": reach.energy_used_J,
        "reserve_J": home.reserve_J,
        "home_reachable": bool(home.reachable),
        "energy_to_home_J": home.energy_to_home_J,
        "duration_to_home_s": home.duration_s,
        "home_reason": home.reason,
        "time_limit_s": reach.time_limit_s,
        "time_used_s": reach.time_used_s,
        "speed_mps": reach.exact.speed_mps,
        "home_return_probability": home.return_probability,
        "goals": [g.to_dict() for g in results],
        "warnings": _warnings(home, results, ctx.scenario.mission.reserve),
    }
    for line in report["warnings"]:
        warn(line)
    if as_json:
        print_json(report)
        return
    _print_report(ctx.scenario.name, report, png)


def _warnings(home, goals: list, reserve) -> list[str]:
    """A line for a way home, and one for all feasible goals, that get home with too low a
    probability (``planning.reach.RETURN_PROBABILITY_WARN``)."""
    from orange_plan.planning.reach import low_return_warning

    lines = [low_return_warning("the way home", home.return_probability, reserve)
             if home.reachable else None]
    risky = [(g.return_probability, g.name or str(i)) for i, g in enumerate(goals)
             if g.feasible and low_return_warning("", g.return_probability, reserve)]
    if risky:
        p, name = min(risky)
        what = (f"{len(risky)} of the {sum(g.feasible for g in goals)} feasible goals "
                f"(lowest: goal {name})")
        lines.append(low_return_warning(what, p, reserve))
    return [line for line in lines if line]


def _kj(value) -> str:
    return "-" if value is None else f"{value / 1e3:,.2f}"


def _print_report(name: str, report: dict, png) -> None:
    out.print(f"[bold]{name}[/]: from ({report['from_xy_m'][0]:g}, {report['from_xy_m'][1]:g}) m, "
              f"{report['energy_used_J'] / 1e3:,.2f} kJ used of "
              f"{report['energy_available_J'] / 1e3:,.2f} kJ, cruise {report['speed_mps']:.2f} m/s")
    if report["time_limit_s"] is not None:
        out.print(f"mission.time_limit_s = {report['time_limit_s']:g} s, "
                  f"{report['time_used_s']:g} s used")
    if report["home_reachable"]:
        out.print(f"home reachable: {_kj(report['energy_to_home_J'])} kJ to home "
                  f"+ {_kj(report['reserve_J'])} kJ reserve")
    else:
        out.print(f"[red]home NOT reachable[/] from the start: {report['home_reason']}")
    if report["goals"]:
        table = Table(show_header=True, header_style="bold")
        for col in ("goal", "x m", "y m", "feasible", "to goal kJ", "home kJ", "margin kJ",
                    "note"):
            table.add_column(col, justify="left" if col in ("goal", "note") else "right",
                             overflow="fold")  # a reason names a key; never cut it
        for i, g in enumerate(report["goals"]):
            table.add_row(g.get("name") or str(i), f"{g['x_m']:g}", f"{g['y_m']:g}",
                          "yes" if g["feasible"] else "[red]no[/]", _kj(g["energy_to_goal_J"]),
                          _kj(g["energy_goal_to_home_J"]), _kj(g["margin_J"]),
                          g.get("reason", ""))
        out.print(table)
    if png is not None:
        out.print(f"wrote {png}")
