"""``orange-plan diagnose``: find the physics the model left out of a recording."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from orange_plan.cli import (
    MAX_GRADE_WINDOW_M,
    RECORDING_HELP,
    SCENARIO_HELP,
    JsonOpt,
    app,
    check_range,
    handles_errors,
    out,
    print_json,
    progress_console,
)

RecordingArg = Annotated[Path, typer.Argument(help=RECORDING_HELP)]
ScenarioOpt = Annotated[Path, typer.Option("--scenario", help=SCENARIO_HELP)]
PngOpt = Annotated[Path | None, typer.Option(
    "--png", help="Write the report figure here: residual before/after over time with the "
                  "located windows, residual against the implicated feature, the fitted term.")]
OutOpt = Annotated[Path | None, typer.Option(
    "-o", "--output", help="Write the scenario with the found terms and fitted values (TOML).")]
GradeOpt = Annotated[float | None, typer.Option(
    "--grade-window-m", help="Elevation smoothing window for the grade, in metres; default: "
                             "the one of 0.5, 2, 5, 10, 20 m that predicts held-out blocks best.")]


@app.command("diagnose")
@handles_errors
def diagnose_cmd(recording: RecordingArg, scenario: ScenarioOpt, png: PngOpt = None,
                 output: OutOpt = None, grade_window_m: GradeOpt = None,
                 as_json: JsonOpt = False) -> None:
    """Locate where a recording and the model disagree, name the missing physics, add it and
    show the fit improve."""
    from orange_plan.context import load_context
    from orange_plan.files import check_output
    from orange_plan.identify.diagnose import diagnose
    from orange_plan.identify.scenario_out import write_calibrated_scenario
    from orange_plan.progress import stages
    from orange_plan.telemetry.recording import load_recording
    from orange_plan.telemetry.replay import check_positions_on_map

    check_range(grade_window_m, "--grade-window-m", high=MAX_GRADE_WINDOW_M)
    if png is not None:
        check_output(png, "--png", [".png"], inputs=[recording, scenario])
    if output is not None:
        check_output(output, "-o", [".toml"], inputs=[recording, scenario])
    with stages(progress_console(as_json)) as step:
        step(f"reading {recording.name}")
        rec = load_recording(recording)
        step("loading the scenario")
        ctx = load_context(scenario)
        check_positions_on_map(rec, ctx.world)
        step(f"diagnosing {len(rec.frame):,} samples")
        result = diagnose(rec, ctx, grade_window_m=grade_window_m)
    report = {"recording": str(recording), "scenario": ctx.scenario.name, **result.to_dict()}
    if output is not None:
        step_out = write_calibrated_scenario(ctx.scenario, result.model, output,
                                             _changes(result.scenario_changes))
        report["output"] = str(step_out)
    if png is not None:
        from orange_plan.viz.diagnose_plot import plot_diagnosis

        plot_diagnosis(result, png, title=f"{recording.name} under {ctx.scenario.name}")
        report["png"] = str(png)
    if as_json:
        print_json(report)
        return
    _print(report)


def _changes(changes: dict) -> dict:
    """Scenario keys a finding changes (a wind); a payload is carried by the coefficients."""
    return {k: v for k, v in changes.items() if "." in k}


def _print(report: dict) -> None:
    base, better = report["baseline"], report["improved"]
    out.print(f"{report['recording']} under {report['scenario']}: {report['verdict']}")
    out.print(f"  baseline ({', '.join(base['terms'])}): RMSE {base['rmse_W']:.3g} W, held out "
              f"{base['holdout_rmse_W']:.3g} W, energy error {base['energy_error_pct']:+.2f} %")
    if report["mismatches"]:
        table = Table(title="Where the model and the recording disagree", header_style="bold")
        for col in ("from [s]", "to [s]", "mean residual [W]", "where"):
            table.add_column(col, justify="left" if col == "where" else "right")
        for m in report["mismatches"]:
            table.add_row(f"{m['t_start_s']:.0f}", f"{m['t_end_s']:.0f}",
                          f"{m['mean_residual_W']:+.3g}", m["where"])
        out.print(table)
    if report["missing_physics"]:
        table = Table(title="Missing physics", header_style="bold")
        for col in ("term", "explains", "parameters (+- 1 sd)"):
            table.add_column(col, justify="left" if col != "explains" else "right")
        for f in report["missing_physics"]:
            name = f["term"] + (f" ({f['variant']})" if f.get("variant") else "")
            params = ", ".join(f"{k} = {v:.4g} +- {f['stderr'].get(k, float('nan')):.2g}"
                               for k, v in f["params"].items())
            table.add_row(name, f"{f['explains_pct']:.0f} %", params)
        out.print(table)
        for f in report["missing_physics"]:
            out.print(f"  evidence: {f['evidence']}", markup=False, highlight=False)
        out.print(f"  improved ({', '.join(better['terms'])}): RMSE {better['rmse_W']:.3g} W, "
                  f"held out {better['holdout_rmse_W']:.3g} W, energy error "
                  f"{better['energy_error_pct']:+.2f} %")
    else:
        out.print(f"  evidence: {report['evidence']}", markup=False, highlight=False)
    for key in ("output", "png"):
        if key in report:
            out.print(f"  wrote {report[key]}")
