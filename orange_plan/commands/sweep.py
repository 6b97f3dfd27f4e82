"""``orange-plan sweep``: scenarios x parameter grid x seeds on Dask, one Parquet row per run."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from orange_plan.cli import JsonOpt, app, handles_errors, out, print_json, progress_console
from orange_plan.files import check_output
from orange_plan.progress import bar


@app.command("sweep")
@handles_errors
def sweep_cmd(
    sweep_file: Annotated[Path, typer.Argument(
        help="Sweep TOML: scenarios, [grid] table of dotted scenario keys, seeds (docs/formats.md).")],
    output: Annotated[Path, typer.Option(
        "-o", "--output", help="Results Parquet, one row per run; an existing one is resumed "
                               "(finished runs are not redone).")],
    workers: Annotated[int, typer.Option(
        help="Worker processes of the local Dask cluster (ignored with --scheduler).")] = 2,
    scheduler: Annotated[str | None, typer.Option(
        help="Address tcp://HOST:PORT of an existing Dask scheduler to use instead of a local "
             "cluster; its workers must have orange-plan and see the sweep's files.")] = None,
    png: Annotated[Path | None, typer.Option(
        help="PNG: coverage and strandings against the first numeric grid key.")] = None,
    as_json: JsonOpt = False,
) -> None:
    """Plan, simulate and score every run of a sweep (scenarios x grid x seeds) on a Dask
    cluster; print a summary per scenario and grid point."""
    from orange_plan.sweep.driver import pending_runs, run_sweep
    from orange_plan.sweep.report import summary_rows, summary_table, sweep_figure
    from orange_plan.sweep.spec import load_sweep
    from orange_plan.sweep.store import ResultStore

    check_output(output, "-o", [".parquet"], inputs=[sweep_file])
    if png is not None:
        check_output(png, "--png", [".png"], inputs=[sweep_file, output])
    sweep = load_sweep(sweep_file)
    store = ResultStore(output)
    todo = len(pending_runs(sweep, store))
    with bar(todo, "runs", progress_console(as_json) if todo > 0 else None) as tick:
        result = run_sweep(sweep, store, workers, scheduler, tick)
    summary = summary_rows(result.rows, sweep.grid_keys)
    title = f"sweep {sweep.name}: {len(result.rows)} runs"
    if png is not None:
        sweep_figure(summary, sweep.grid_keys, title, png)
    if as_json:
        print_json({"sweep": sweep.name, "results": str(output), "runs": len(result.rows),
                    "ran": result.ran, "resumed": result.skipped,
                    "compute_s": result.compute_s, "summary": summary})
        return
    out.print(summary_table(summary, sweep.grid_keys, title))
    out.print(f"wrote {output}: {len(result.rows)} rows ({result.ran} run now, "
              f"{result.skipped} already stored) in {result.compute_s:.1f} s"
              + (f"; wrote {png}" if png is not None else ""), highlight=False)
