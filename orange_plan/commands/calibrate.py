"""``orange-plan calibrate``: fit the model's coefficients to recordings."""

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
    err,
    handles_errors,
    out,
    print_json,
)

RecordingsArg = Annotated[list[Path], typer.Argument(help=RECORDING_HELP)]
ScenarioOpt = Annotated[Path, typer.Option("--scenario", help=SCENARIO_HELP)]
OutOpt = Annotated[Path | None, typer.Option(
    "-o", "--output", help="Write the scenario with the fitted values here (TOML).")]
TermsOpt = Annotated[str | None, typer.Option(
    "--terms", help="Comma-separated physics term ids to fit (see the term table of docs/guide/range.md), "
                    "e.g. ancillary,sensor_rate,rolling,surface_rolling; default: the "
                    "scenario's model.")]
FixedOpt = Annotated[str | None, typer.Option(
    "--fixed", help="Comma-separated coefficient names to hold at the scenario's values.")]
NoPriorOpt = Annotated[bool, typer.Option(
    "--no-prior", help="Plain least squares, without the scenario's values as a prior.")]
GradeOpt = Annotated[float | None, typer.Option(
    "--grade-window-m", help="Elevation smoothing window for the grade, in metres (lab ramps: ~1).")]


def _split(text: str | None):
    return None if text is None else [t.strip() for t in text.split(",") if t.strip()]


@app.command("calibrate")
@handles_errors
def calibrate_cmd(recordings: RecordingsArg, scenario: ScenarioOpt, output: OutOpt = None,
                  terms: TermsOpt = None, fixed: FixedOpt = None, no_prior: NoPriorOpt = False,
                  grade_window_m: GradeOpt = None, as_json: JsonOpt = False) -> None:
    """Fit the scenario's term coefficients (with uncertainties) to one or more recordings."""
    from orange_plan.context import load_context
    from orange_plan.files import check_output
    from orange_plan.identify.calibrate import Calibrator
    from orange_plan.identify.scenario_out import write_calibrated_scenario
    from orange_plan.physics.model_builder import physical_values
    from orange_plan.telemetry.recording import load_recording
    from orange_plan.telemetry.replay import check_positions_on_map

    check_range(grade_window_m, "--grade-window-m", high=MAX_GRADE_WINDOW_M)
    if output is not None:
        check_output(output, "-o", [".toml"], inputs=[*recordings, scenario])
    ctx = load_context(scenario)
    recs = [load_recording(p) for p in recordings]
    for rec in recs:
        check_positions_on_map(rec, ctx.world)
    cal = Calibrator(terms=_split(terms), fixed=_split(fixed) or (), use_prior=not no_prior,
                     grade_window_m=grade_window_m).fit(recs, ctx)
    report = {
        "scenario": ctx.scenario.name,
        "terms": list(cal.model_.term_ids),
        "params": cal.theta_,
        "stderr": cal.stderr_,
        "fit": cal.fit_report_.to_dict(),
        "physical": physical_values(ctx.scenario, cal.model_),
        "surface_crr": cal.surface_crr_,
    }
    if output is not None:
        write_calibrated_scenario(ctx.scenario, cal.model_, output)
        report["output"] = str(output)
    if as_json:
        print_json(report)
        _warn(cal.fit_report_)
        return
    out.print(_table(cal))
    fit = cal.fit_report_
    out.print(f"RMSE {fit.rmse_W:.3g} W; held out: RMSE {fit.holdout_rmse_W:.3g} W, energy "
              f"error {fit.energy_error_pct:.2f} %; residual autocorrelation x{fit.inflation:.1f}")
    source = (f"from {fit.discrepancy_runs} held-out recordings" if fit.discrepancy_runs
              else "a priori: one recording shows nothing run-to-run")
    out.print(f"run-to-run discrepancy: {100 * fit.discrepancy_rel_sd:.1f} % of a run's energy "
              f"({source})")
    if cal.surface_crr_:
        out.print("crr per surface: " + ", ".join(f"{k} {v:.4f}" for k, v in cal.surface_crr_.items()))
    if output is not None:
        out.print(f"wrote {output}")
    _warn(fit)


def _warn(fit) -> None:
    """One stderr line per constraint outcome (also under --json: stdout stays one object)."""
    if fit.held_at_prior:
        err.print(f"warning: held at the prior (the data cannot pin them): "
                  f"{', '.join(fit.held_at_prior)}", soft_wrap=True)
    if fit.clipped:
        err.print(f"warning: on the bound of the physical range (the data pull beyond it): "
                  f"{', '.join(fit.clipped)}", soft_wrap=True)
    if fit.unphysical:
        err.print(f"warning: outside the physical range (fixed values): "
                  f"{', '.join(fit.unphysical)}", soft_wrap=True)


def _table(cal) -> Table:
    table = Table(title="Calibrated coefficients", header_style="bold")
    for col in ("coefficient", "fitted", "stderr", "prior", "note"):
        table.add_column(col, justify="left" if col in ("coefficient", "note") else "right")
    fit = cal.fit_report_
    for name, value in cal.theta_.items():
        note = ("held at prior" if name in fit.held_at_prior
                else "on bound" if name in fit.clipped else "")
        table.add_row(name, f"{value:.5g}", f"{cal.stderr_[name]:.3g}",
                      f"{cal.prior_.get(name, float('nan')):.5g}", note)
    return table
