"""``orange-plan bench check``: how fast ``check`` answers on a long survey mission.

Registered on the ``bench`` group of ``commands/bench.py`` from here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from orange_plan.cli import JsonOpt, bench_app, handles_errors, out, print_json
from orange_plan.errors import InputError


@bench_app.command("check")
@handles_errors
def bench_check_cmd(
    scenario: Annotated[Path | None, typer.Argument(
        help="Scenario TOML (default: the quadrotor, scenarios/ar_drone_wind.toml).")] = None,
    waypoints: Annotated[int, typer.Option(
        "--waypoints", help="Waypoints of the survey (2 to 10,000).")] = 500,
    repeats: Annotated[int, typer.Option(help="In-process repeats (median reported).")] = 3,
    as_json: JsonOpt = False,
) -> None:
    """Time 'check' on a lawnmower survey of the scenario's map written as a .plan: reading,
    checking (in-process, median) and the whole command in a fresh process."""
    from orange_plan.bench.check import run_check_bench
    from orange_plan.limits import MAX_MISSION_WAYPOINTS

    if not 2 <= waypoints <= MAX_MISSION_WAYPOINTS:
        raise InputError(f"--waypoints = {waypoints} must be from 2 to "
                         f"{MAX_MISSION_WAYPOINTS:,}")
    if not 1 <= repeats <= 100:
        raise InputError(f"--repeats = {repeats} must be from 1 to 100")
    if scenario is None:
        from orange_plan.examples import examples_dir

        scenario = examples_dir("scenarios", "a SCENARIO argument") / "ar_drone_wind.toml"
    result = run_check_bench(scenario, waypoints, repeats)
    if as_json:
        print_json(result.to_dict())
        return
    table = Table(title=f"bench check: {result.scenario}, {result.waypoints} waypoints, "
                        f"{result.route_m / 1e3:,.1f} km ({result.verdict})",
                  header_style="bold")
    for col in ("measure", "measured", "target"):
        table.add_column(col, justify="left" if col == "measure" else "right")
    table.add_row(f"read the .plan (median of {result.repeats})", f"{result.read_s:.3f} s", "")
    table.add_row(f"check {result.legs} legs and every way home (median)",
                  f"{result.check_s:.3f} s", "")
    table.add_row("read + check", f"{result.read_s + result.check_s:.3f} s",
                  f"<= {result.target_s:g} s")
    table.add_row("whole command, fresh process (imports included): wall clock",
                  f"{result.command_s:.2f} s", "")
    table.add_row("whole command, fresh process: CPU time (user + system)",
                  f"{result.command_cpu_s:.2f} s", "")
    out.print(table)
