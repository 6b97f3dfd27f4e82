"""``orange-plan bench replan``: how fast a mid-mission replan is (target)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from orange_plan.cli import (
    JsonOpt,
    bench_app,
    default_scenario,
    handles_errors,
    out,
    print_json,
    progress_console,
)
from orange_plan.errors import InputError
from orange_plan.progress import bar


@bench_app.command("replan")
@handles_errors
def bench_replan_cmd(
    scenario: Annotated[Path | None, typer.Argument(
        help="Scenario TOML (default: the hilly example, scenarios/kiwibot_campus.toml).")] = None,
    replans: Annotated[int, typer.Option(help="Warm replans along the first plan.")] = 40,
    vertices: Annotated[int, typer.Option(help="Roadmap vertices.")] = 5000,
    seed: Annotated[int, typer.Option(help="Seed of the roadmap and the drawn models.")] = 0,
    as_json: JsonOpt = False,
) -> None:
    """Time replans from states along a plan, each with a model drawn from the scenario's
    covariance (median and p95 against the 250 ms target; wall clock and CPU time)."""
    from orange_plan.bench.replan import run_replan_bench
    from orange_plan.context import load_context

    if replans < 1:
        raise InputError(f"--replans = {replans} must be >= 1")
    ctx = load_context(scenario or default_scenario())
    with bar(replans, "replans", progress_console(as_json)) as tick:
        result = run_replan_bench(ctx, replans, vertices, seed, tick)
    if as_json:
        print_json(result.to_dict())
        return
    table = Table(title=f"{result.scenario}: replanning ({result.replans} warm replans)")
    for col in ("cold plan s", "median s", "p95 s", "max s", "p95 / target", "CPU median s",
                "CPU p95 s", "all safe", "nothing fits"):
        table.add_column(col, justify="right")
    table.add_row(f"{result.cold_s:.2f}", f"{result.median_s:.3f}", f"{result.p95_s:.3f}",
                  f"{result.max_s:.3f}", f"{result.p95_s / result.target_p95_s:.2f}",
                  f"{result.cpu_median_s:.3f}", f"{result.cpu_p95_s:.3f}",
                  "yes" if result.all_safe else "NO", str(result.nothing_fits))
    out.print(table)
    out.print("load average (1/5/15 min): " + " ".join(f"{v:.2f}" for v in result.load_before)
              + " -> " + " ".join(f"{v:.2f}" for v in result.load_after))
