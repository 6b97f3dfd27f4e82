"""``orange-plan bench calibration|online``: offline vs online range and calibration on held-out recordings.

The subcommands sit on the ``bench`` group of ``commands/bench.py`` (registered from here,
so that file needs no edit).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from orange_plan.cli import JsonOpt, bench_app, handles_errors, out, print_json, progress_console
from orange_plan.progress import bar

DataOpt = Annotated[Path | None, typer.Option(
    "--data", help="Folder with the real data sets' borealtc/ and tum_bmw_i3/ folders (not "
                   "shipped with the package; default: the first of ./data, ../shared/data and "
                   "<prefix>/share/orange-plan/data that exists).")]
ScenariosOpt = Annotated[Path | None, typer.Option(
    "--scenarios", help="Folder of scenario TOML files (default: the shipped examples).")]
SeedsOpt = Annotated[int, typer.Option("--seeds", help="Simulated runs per scenario.")]
PngOpt = Annotated[Path | None, typer.Option(
    "--png", help="Figure of the range estimates over the first run of each scenario.")]
OnlyOpt = Annotated[str | None, typer.Option(
    "--only", help="Comma-separated subset (datasets or scenario names).")]


def _scenarios(folder: Path | None) -> Path:
    from orange_plan.examples import examples_dir

    return folder if folder is not None else examples_dir("scenarios", "--scenarios")


def _default_data() -> Path:
    """The data sets' folder by the examples' look-up rule; otherwise --data is required."""
    from orange_plan.examples import examples_dir

    return examples_dir("data", "--data")


def _split(text):
    return None if text is None else [t.strip() for t in text.split(",") if t.strip()]


@bench_app.command("calibration")
@handles_errors
def calibration_cmd(data: DataOpt = None, scenarios: ScenariosOpt = None, only: OnlyOpt = None,
                    as_json: JsonOpt = False) -> None:
    """Fit on every other real run, predict the others' whole-run energy (two folds)."""
    from orange_plan.bench.identify import (
        CALIBRATION_CASES,
        calibration_benchmark,
        count_runs,
        summarise_calibration,
    )
    from orange_plan.errors import InputError
    from orange_plan.files import require_folder

    names = _split(only) or list(CALIBRATION_CASES)
    unknown = [n for n in names if n not in CALIBRATION_CASES]
    if unknown:
        raise InputError(f"unknown dataset '{unknown[0]}'; known: {', '.join(CALIBRATION_CASES)}")
    data = require_folder(data, "--data") if data is not None else _default_data()
    scenarios = _scenarios(scenarios)
    with bar(count_runs(data, names), "held-out runs", progress_console(as_json)) as tick:
        rows = calibration_benchmark(data, scenarios, names, progress=tick)
    summary = summarise_calibration(rows)
    if as_json:
        print_json({"summary": summary, "runs": [r.to_dict() for r in rows]})
        return
    table = Table(title="Whole-run energy error on held-out runs (2-fold)", header_style="bold",
                  caption="offline: the model alone; online: measured so far + live coefficients "
                          "on the rest, at 20 % of the run (mean over 20-80 %)")
    for col in ("dataset", "runs", "mean |err| %", "median |err| %", "max |err| %",
                "pooled err %", "a priori mean |err| %", "online @20 % mean |err| %",
                "online from a priori @20 %"):
        table.add_column(col, justify="left" if col == "dataset" else "right")
    for s in summary:
        table.add_row(s["dataset"], str(s["held_out_runs"]), f"{s['mean_abs_error_pct']:.1f}",
                      f"{s['median_abs_error_pct']:.1f}", f"{s['max_abs_error_pct']:.1f}",
                      f"{s['pooled_error_pct']:+.1f}", f"{s['mean_abs_error_prior_pct']:.1f}",
                      f"{s['online_mean_abs_error_pct']:.1f} "
                      f"({s['online_mean_abs_error_over_run_pct']:.1f})",
                      f"{s['online_prior_mean_abs_error_pct']:.1f}")
    out.print(table)
    out.print(_coverage_table(summary, "dataset", "Held-out real runs whose recorded energy "
                              "exceeds predicted + reserve(p)", prior_only=False))


def _coverage_table(summary, key: str, title: str, prior_only: bool) -> Table:
    """Exceedance of predicted + reserve(p) (honest: at most 100 (1 - p) %), a priori and
    calibrated, with the mean relative predictive sd the reserve was sized from."""
    from orange_plan.bench.identify import RESERVE_CONFIDENCES

    table = Table(title=title, header_style="bold",
                  caption="reserve(p) = z_p x predictive sd (coefficient covariance + run-to-run "
                          "discrepancy); honest when exceeded in <= 100 (1 - p) % of runs; in "
                          "brackets: the reserve from the coefficient covariance alone")
    models = [("a priori", "_prior")] + ([] if prior_only else [("calibrated", "")])
    table.add_column(key, justify="left")
    for label, _ in models:
        table.add_column(f"{label}: sd / E", justify="right")
        for p in RESERVE_CONFIDENCES:
            table.add_column(f"{label}: > reserve({p:g})", justify="right")
    for s in summary:
        cells = [str(s[key])]
        for _, suffix in models:
            cells.append(f"{100 * s[f'sd_rel{suffix}_mean']:.1f} %")
            for p in RESERVE_CONFIDENCES:
                tag = f"p{round(100 * p)}{suffix}"
                cells.append(f"{_share(s, tag)} ({_share(s, tag + '_param')})")
        table.add_row(*cells)
    return table


def _share(summary: dict, tag: str) -> str:
    return f"{summary[f'exceed_{tag}_pct']:.1f} % / {summary[f'exceed_{tag}_runs']}"


@bench_app.command("online")
@handles_errors
def online_cmd(scenarios: ScenariosOpt = None, seeds: SeedsOpt = 3,
               only: OnlyOpt = None, png: PngOpt = None, as_json: JsonOpt = False) -> None:
    """Offline vs online range accuracy on simulated runs to depletion."""
    from orange_plan.bench.identify import BENCH_TRUTHS, online_benchmark, summarise
    from orange_plan.errors import InputError

    names = _split(only) or list(BENCH_TRUTHS)
    if png is not None:
        from orange_plan.files import check_output

        check_output(png, "--png", [".png"])
    if seeds < 1:
        raise InputError(f"--seeds = {seeds} must be >= 1")
    scenarios = _scenarios(scenarios)
    with bar(len(names) * seeds, "simulating runs to depletion", progress_console(as_json)) as tick:
        rows = online_benchmark(scenarios, names, tuple(range(seeds)), progress=tick)
    summary = summarise(rows)
    report = {"summary": summary, "runs": [r.to_dict() for r in rows]}
    if png is not None:
        from orange_plan.bench.identify import online_trace
        from orange_plan.context import load_context
        from orange_plan.viz.online_plot import plot_online_traces

        traces = [online_trace(load_context(scenarios / f"{n}.toml"), BENCH_TRUTHS.get(n, {}),
                               0)[0] for n in names]
        plot_online_traces(traces, png)
        report["png"] = str(png)
    if as_json:
        print_json(report)
        return
    table = Table(title="Range accuracy, simulated runs to depletion", header_style="bold")
    for col in ("scenario", "runs", "d_true m", "offline %", "online @20 % %",
                "online mean 20-80 % %"):
        table.add_column(col, justify="left" if col == "scenario" else "right")
    for s in summary:
        table.add_row(s["scenario"], str(s["runs"]), f"{s['d_true_m']:,.0f}",
                      f"{s['accuracy_offline_pct']:.1f}", f"{s['accuracy_online_pct']:.1f}",
                      f"{s['accuracy_online_mean_pct']:.1f}")
    out.print(table)
    out.print(_coverage_table(summary, "scenario", "Simulated runs whose energy exceeds the "
                              "a-priori prediction + reserve(p)", prior_only=True))
    if png is not None:
        out.print(f"figure: {png}")
