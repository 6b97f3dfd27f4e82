"""``orange-plan bench concealed``: generate the concealed-effect cases of diagnosis, timed.

Registered on the ``bench`` group of ``commands/bench.py`` from here.
"""

from __future__ import annotations

from typing import Annotated

import typer
from rich.table import Table

from orange_plan.cli import JsonOpt, bench_app, handles_errors, out, print_json, progress_console
from orange_plan.progress import bar


@bench_app.command("concealed")
@handles_errors
def concealed_cmd(
    seeds: Annotated[int, typer.Option("--seeds", help="Seeds per case (0, 1, ...).")] = 3,
    duration_s: Annotated[float, typer.Option("--duration-s", help="Run length [s].")] = 1800.0,
    rate_Hz: Annotated[float, typer.Option("--rate-hz", help="Recording rate [Hz].")] = 10.0,
    only: Annotated[str | None, typer.Option(
        "--only", help="Comma-separated case labels (e.g. turning,wind+payload,null-ground).")]
        = None,
    as_json: JsonOpt = False,
) -> None:
    """Concealed-effect cases: generation time and how far the given scenario misses them."""
    from orange_plan.bench.concealed import concealed_benchmark, labels_of, summarise_concealed
    from orange_plan.errors import InputError

    if seeds < 1:
        raise InputError(f"--seeds = {seeds} must be >= 1")
    labels = [t.strip() for t in only.split(",") if t.strip()] if only else None
    total = seeds * len(labels_of(labels))
    with bar(total, "generating cases", progress_console(as_json)) as tick:
        rows = concealed_benchmark(range(seeds), duration_s, rate_Hz, labels, progress=tick)
    summary = summarise_concealed(rows)
    if as_json:
        print_json({"summary": summary, "cases": [r.to_dict() for r in rows]})
        return
    table = Table(title=f"Concealed-effect cases, {duration_s:g} s at {rate_Hz:g} Hz",
                  header_style="bold", caption="|energy error|: the given scenario's predict "
                  "error on the recording (what the concealed physics carries)")
    for col in ("case", "kind", "seeds", "generate s (median)", "|energy error| % median",
                "min..max", "RMSE W median"):
        table.add_column(col, justify="left" if col in ("case", "kind") else "right")
    for s in summary:
        table.add_row(s["label"], s["kind"], str(s["cases"]), f"{s['seconds_median']:.2f}",
                      f"{s['abs_energy_error_pct_median']:.1f}",
                      f"{s['abs_energy_error_pct_min']:.1f}..{s['abs_energy_error_pct_max']:.1f}",
                      f"{s['rmse_W_median']:.1f}")
    out.print(table)
