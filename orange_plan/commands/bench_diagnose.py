"""``orange-plan bench diagnose``: diagnosis vs a sparse regression on concealed effects."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from orange_plan.cli import JsonOpt, bench_app, handles_errors, out, print_json, progress_console
from orange_plan.progress import bar

SeedsOpt = Annotated[str, typer.Option(
    "--seeds", help="Comma-separated seeds of the generated cases (the tests use 0 and 1).")]
DurationOpt = Annotated[float, typer.Option("--duration-s", help="Length of each recording [s].")]
RateOpt = Annotated[float, typer.Option("--rate-hz", help="Recording rate [Hz].")]
OnlyOpt = Annotated[str | None, typer.Option(
    "--only", help="Comma-separated case names to generate and diagnose, the others "
                    "skipped (e.g. turning,null-ground).")]
CsvOpt = Annotated[Path | None, typer.Option("--csv", help="Write the per-case rows here.")]
RealOpt = Annotated[Path | None, typer.Option(
    "--real", help="Instead of the generated cases: the BMW i3 trips under this data folder "
                   "(tum_bmw_i3/Trip*.csv.gz), diagnosed without inertia and regen.")]


@bench_app.command("diagnose")
@handles_errors
def diagnose_bench_cmd(seeds: SeedsOpt = "101,102,103", duration_s: DurationOpt = 1800.0,
                       rate_hz: RateOpt = 10.0, only: OnlyOpt = None, csv: CsvOpt = None,
                       real: RealOpt = None, as_json: JsonOpt = False) -> None:
    """Concealed-effect cases: terms found, false positives, held-out RMSE and seconds of
    the diagnosis and of a LassoCV sparse regression over the same candidate features;
    with --real, regeneration on the BMW i3 trips."""
    if real is not None:
        _real_trips(real, as_json)
        return
    from orange_plan.bench.diagnose import compare, summarise
    from orange_plan.errors import InputError
    from orange_plan.files import check_output
    from orange_plan.sim.concealed import concealed_suite

    try:
        seed_list = [int(s) for s in seeds.split(",") if s.strip()]
    except ValueError:
        raise InputError(f"--seeds must be comma-separated integers, got {seeds!r}") from None
    if not seed_list:
        raise InputError("--seeds names no seed")
    if csv is not None:
        check_output(csv, "--csv", [".csv"])
    keep = None if only is None else {s.strip() for s in only.split(",") if s.strip()}
    cases = concealed_suite(seed_list, duration_s=duration_s, rate_Hz=rate_hz, only=keep)
    if not cases:
        raise InputError(f"--only {only!r} keeps no case")
    rows = []
    with bar(len(cases), "diagnosing concealed cases", progress_console(as_json)) as tick:
        for case in cases:
            rows.append(compare(case))
            if tick:
                tick()
    summary = summarise(rows)
    if csv is not None:
        import pandas as pd

        from orange_plan.atomic import atomic_path

        with atomic_path(csv, suffix=".csv") as tmp:
            pd.DataFrame([r.to_dict() for r in rows]).to_csv(tmp, index=False)
    if as_json:
        print_json({"summary": summary, "rows": [r.to_dict() for r in rows]})
        return
    out.print(_summary_table(summary))
    out.print(_rows_table(rows))


def _real_trips(data_dir: Path, as_json: bool) -> None:
    """``--real``: each BMW i3 trip with the regeneration diagnosis found."""
    from orange_plan.bench.diagnose_real import bmw_regen
    from orange_plan.examples import examples_dir

    rows = bmw_regen(data_dir, examples_dir("scenarios", "--scenarios") / "bmw_i3.toml")
    if as_json:
        print_json({"rows": [r.to_dict() for r in rows]})
        return
    table = Table(title="BMW i3 trips, scenario without inertia and regen", header_style="bold")
    for col in ("trip", "found", "regen t", "regen efficiency", "95 % interval",
                "braking samples", "held-out RMSE [W] inertia / + regen", "gain",
                "torque signal's efficiency", "seconds"):
        table.add_column(col)
    for r in rows:
        table.add_row(r.trip, ",".join(r.found) or "-", f"{r.regen_t:.1f}",
                      f"{r.regen_efficiency:.2f} +- {r.regen_efficiency_sd:.2f}",
                      f"{r.efficiency_low:.2f}-{r.efficiency_high:.2f}",
                      f"{100 * r.braking_share:.0f} %",
                      f"{r.inertia_holdout_rmse_W:.0f} / {r.inertia_regen_holdout_rmse_W:.0f}",
                      f"{r.regen_gain_pct:.1f} %", f"{r.torque_efficiency:.2f}",
                      f"{r.seconds:.1f}")
    out.print(table)


def _summary_table(summary: dict) -> Table:
    table = Table(title=f"{summary['cases']} concealed-effect cases ({summary['null_cases']} "
                        "with nothing missing)", header_style="bold")
    for col in ("method", "terms found", "false positives (on nulls)",
                "median held-out RMSE gain", "median / max seconds"):
        table.add_column(col, justify="left" if col == "method" else "right")
    for key, label in (("diagnosis", "diagnosis"), ("sparse_regression", "LassoCV")):
        m = summary[key]
        table.add_row(label, f"{m['terms_found']} / {m['terms_concealed']}",
                      f"{m['false_positives']} ({m['false_positives_on_nulls']})",
                      f"{m['median_holdout_improvement_pct']:.1f} %",
                      f"{m['median_seconds']:.2f} / {m['max_seconds']:.2f}")
    hidden = "; ".join(summary["undetectable"]) or "none"
    table.caption = (f"parameters within 3 sd: {summary['params_within_3sd']} / "
                     f"{summary['params']}, median relative error "
                     f"{100 * summary['params_median_rel_error']:.1f} %\n"
                     f"detectable when told the true terms: {summary['terms_detectable']}, "
                     f"of which diagnosis found {summary['detectable_found']}; "
                     f"hidden by the noise: {hidden}\n"
                     f"misses under the detection limit diagnosis stated for them: "
                     f"{summary['misses_under_stated_limit']} of {summary['misses']}\n"
                     f"misses the stated limits predict: {summary['misses_expected']:.1f} "
                     f"(observed {summary['misses']}); of the "
                     f"{summary['terms_above_stated_limit']} terms above their limit, "
                     f"{summary['misses_expected_above_stated_limit']:.2f} "
                     f"(observed {summary['misses_above_stated_limit']})")
    return table


def _rows_table(rows) -> Table:
    table = Table(title="per case", header_style="bold")
    for col in ("case", "concealed", "diagnosis named", "LassoCV named", "held-out RMSE [W] "
                "base / ours / lasso", "seconds ours / lasso"):
        table.add_column(col)
    for r in rows:
        table.add_row(r.case, ",".join(r.concealed) or "-", ",".join(r.ours_named) or "-",
                      ",".join(r.lasso_named) or "-",
                      f"{r.baseline_holdout_rmse_W:.3g} / {r.ours_holdout_rmse_W:.3g} / "
                      f"{r.lasso_holdout_rmse_W:.3g}",
                      f"{r.ours_seconds:.2f} / {r.lasso_seconds:.2f}")
    return table
