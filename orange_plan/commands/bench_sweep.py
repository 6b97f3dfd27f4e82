"""``orange-plan bench sweep``: Dask speed-up from 1 to 2 workers, and a killed sweep resumed
(targets)."""

from __future__ import annotations

import tempfile
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
from orange_plan.progress import stages


@bench_app.command("sweep")
@handles_errors
def bench_sweep_cmd(
    scenario: Annotated[Path | None, typer.Argument(
        help="Scenario of the timed sweep (default: scenarios/kiwibot_campus.toml).")] = None,
    runs: Annotated[int, typer.Option(help="Runs (seeds) of the timed sweep.")] = 12,
    repeats: Annotated[int, typer.Option(help="Timings per worker count (median).")] = 3,
    vertices: Annotated[int, typer.Option(help="Roadmap vertices of the timed runs.")] = 1000,
    resume_runs: Annotated[int, typer.Option(
        help="Runs of the kill-and-resume check (0: skip it).")] = 200,
    as_json: JsonOpt = False,
) -> None:
    """Time one sweep on a local Dask cluster of 1 and of 2 workers (speed-up target >= 1.7);
    kill a sweep halfway and rerun it (target: exactly as many rows as runs, none redone)."""
    from orange_plan.bench.maps import random_scenario
    from orange_plan.bench.sweep import run_resume_check, run_speedup_bench

    for name, value, low in (("--runs", runs, 2), ("--repeats", repeats, 1),
                             ("--vertices", vertices, 50)):
        if value < low:
            raise InputError(f"{name} = {value} must be >= {low}")
    if resume_runs != 0 and resume_runs < 4:
        raise InputError(f"--resume-runs = {resume_runs} must be >= 4 (or 0 to skip)")
    result = {}
    with stages(progress_console(as_json)) as step:
        result["speedup"] = run_speedup_bench(scenario or default_scenario(), runs, repeats,
                                              vertices, step)
        if resume_runs:
            with tempfile.TemporaryDirectory(prefix="orange-bench-resume-map-") as folder:
                small = random_scenario(Path(folder), 0, width_m=80.0, height_m=60.0)
                result["resume"] = run_resume_check(small, resume_runs, resume_runs // 2,
                                                    step=step)
    if as_json:
        print_json(result)
        return
    out.print(sweep_bench_table(result))


def sweep_bench_table(result: dict) -> Table:
    """Measured against the targets (the table of docs/benchmarks/sweep.md)."""
    s = result["speedup"]
    t = Table(title=f"bench sweep: {s['runs']} runs of {s['scenario']} ({s['vertices']} "
              f"vertices), median of {s['repeats']}; load {s['load_1min'][0]:.1f}..."
              f"{max(s['load_1min']):.1f} on {s['cpus']} CPUs", header_style="bold")
    for col in ("measure", "measured", "target"):
        t.add_column(col, justify="left" if col == "measure" else "right")
    t.add_row("sweep time, 1 worker / 2 workers",
              f"{s['median_1_worker_s']:.1f} s / {s['median_2_workers_s']:.1f} s", "")
    t.add_row("speed-up 1 -> 2 workers", f"{s['speedup']:.2f} x",
              f">= {s['targets']['speedup_1_to_2']:g} x")
    t.add_row("one run (median), 1 worker / 2 workers",
              f"{s['median_run_s']:.2f} s / {s['median_run_s_2_workers']:.2f} s", ">= 1 s")
    t.add_row("workers busy in runs, 1 worker / 2 workers",
              f"{s['busy_1_worker']:.0%} / {s['busy_2_workers']:.0%}", "")
    r = result.get("resume")
    if r:
        t.add_row(f"{r['runs']}-run sweep killed at {r['rows_at_kill']} rows, rerun: rows",
                  f"{r['final_rows']} ({r['unique_ids']} ids)", f"= {r['runs']}")
        t.add_row("rows redone / processes left by the kill",
                  f"{r['redone']} / {r['stray_processes']}", "0 / 0")
        t.add_row("rerun: resumed + ran", f"{r['resumed']} + {r['ran_after']}", "")
    return t
