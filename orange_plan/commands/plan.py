"""``orange-plan plan``: an exploration tour that maximises coverage and always gets home."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

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
from orange_plan.files import check_output
from orange_plan.limits import MAX_ROADMAP_VERTICES, MIN_ROADMAP_VERTICES
from orange_plan.progress import stages


@app.command("plan")
@handles_errors
def plan_cmd(
    scenario: ScenarioArg,
    output: Annotated[Path, typer.Option(
        "-o", "--output", help="Plan GeoJSON to write (tour, waypoints, covered area, summary).")],
    png: Annotated[Path | None, typer.Option(
        "--png", help="Also draw the plan: map, tour coloured by speed, covered area, "
                      "energy and homing margin against time.")] = None,
    from_xy: Annotated[str | None, typer.Option(
        "--from", help="Start position X,Y in metres (default: home).")] = None,
    energy_used_J: Annotated[float, typer.Option(
        "--energy-used-J", help="Battery energy already used at the start [J].")] = 0.0,
    time_s: Annotated[float, typer.Option(
        "--time-s", help="Mission time already elapsed at the start [s].")] = 0.0,
    cost: Annotated[str, typer.Option(
        help="Edge cost: 'physics' (the energy model) or 'distance' (constant energy per "
             "metre on flat default ground, for comparison).")] = "physics",
    vertices: Annotated[int, typer.Option(
        help=f"Roadmap vertices ({MIN_ROADMAP_VERTICES} to {MAX_ROADMAP_VERTICES:,}).")] = 5000,
    seed: Annotated[int, typer.Option(help="Roadmap random seed.")] = 0,
    as_json: JsonOpt = False,
) -> None:
    """Plan an exploration tour: the most area sensed on one discharge, with the energy to
    get home (plus the reserve) kept at every vertex."""
    from orange_plan.context import load_context
    from orange_plan.planning.plan import StartState
    from orange_plan.planning.tour import plan_tour

    check_output(output, "-o", [".geojson", ".json"], inputs=[scenario])
    if png is not None:
        check_output(png, "--png", [".png"], inputs=[scenario, output])
    start_xy = parse_xy(from_xy, "--from") if from_xy is not None else None
    check_range(energy_used_J, "--energy-used-J", low_open=False)
    check_range(time_s, "--time-s", high=MAX_TIME_S, low_open=False)
    with stages(progress_console(as_json)) as step:
        step("loading scenario")
        ctx = load_context(scenario)
        start = StartState(start_xy, float(energy_used_J), float(time_s))
        plan = plan_tour(ctx, start, cost=cost, n_vertices=vertices, seed=seed, progress=step)
        plan.write(output)
        if png is not None:
            from orange_plan.viz.plan_plot import plot_plan

            step("drawing the plan")
            plot_plan(ctx.world, plan, png, f"{ctx.scenario.name}: exploration plan ({cost})")
    from orange_plan.planning.reach import low_return_warning

    low = low_return_warning("the plan", plan.summary["return_probability"],
                             ctx.scenario.mission.reserve)
    report = {"scenario": ctx.scenario.name, "plan": str(output), **plan.summary,
              "warnings": [low] if low else []}
    for line in report["warnings"]:
        warn(line)
    if as_json:
        print_json(report)
        return
    _print_summary(report, png)


def _print_summary(s: dict, png) -> None:
    kj = 1e-3
    out.print(f"[bold]{s['scenario']}[/]: wrote {s['plan']}")
    out.print(f"coverage {s['coverage_m2']:,.0f} m^2 ({100 * s['coverage_fraction']:.1f} % of the "
              f"free area; physical bound {s['coverage_bound_m2']:,.0f} m^2)")
    out.print(f"energy planned {s['energy_planned_J'] * kj:,.2f} kJ + reserve "
              f"{s['reserve_J'] * kj:,.2f} kJ of {s['energy_available_J'] * kj:,.2f} kJ available; "
              f"smallest homing margin {s['min_margin_J'] * kj:,.2f} kJ")
    out.print(f"duration {s['duration_s'] / 60:,.1f} min, {s['candidates_visited']} coverage "
              f"candidates, return probability {s['return_probability']:.4f}, planned in "
              f"{s['planner_seconds']:.1f} s")
    if "closed_loop_coverage_m2" in s:
        out.print(f"pattern: {s['pattern']}; flown in closed loop (turning home on the measured "
                  f"energy) it is expected to cover {s['closed_loop_coverage_m2']:,.0f} m^2 "
                  f"(the plan's continuation, {s['closed_loop_turn_m']:,.0f} m of route "
                  f"against {s['guaranteed_length_m']:,.0f} m guaranteed)")
    if png is not None:
        out.print(f"wrote {png}")
