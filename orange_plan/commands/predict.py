"""``orange-plan predict``: replay a recording's motion through the model."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from orange_plan.cli import (
    RECORDING_HELP,
    SCENARIO_HELP,
    JsonOpt,
    app,
    handles_errors,
    out,
    print_json,
    progress_console,
)

RecordingArg = Annotated[Path, typer.Argument(help=RECORDING_HELP)]
ScenarioOpt = Annotated[Path, typer.Option("--scenario", help=SCENARIO_HELP)]
PngOpt = Annotated[Path | None, typer.Option("--png", help="Write recorded vs predicted power here.")]


@app.command("predict")
@handles_errors
def predict_cmd(recording: RecordingArg, scenario: ScenarioOpt, png: PngOpt = None,
                as_json: JsonOpt = False) -> None:
    """Replay a recording's motion through the scenario's model: energy and power error."""
    from orange_plan.context import load_context
    from orange_plan.files import check_output
    from orange_plan.progress import stages
    from orange_plan.telemetry.recording import cumulative_J, load_recording
    from orange_plan.telemetry.replay import check_positions_on_map, replay_context

    if png is not None:
        check_output(png, "--png", [".png"], inputs=[recording, scenario])
    with stages(progress_console(as_json)) as step:
        step(f"reading {recording.name}")
        rec = load_recording(recording)
        step("loading the scenario")
        ctx = load_context(scenario)
        check_positions_on_map(rec, ctx.world)
        step(f"replaying {len(rec.frame):,} samples")
        result = replay_context(rec, ctx)
    report = result.to_dict()
    report["scenario"] = ctx.scenario.name
    report["issues"] = [i.to_dict() for i in rec.issues]
    if png is not None:
        from orange_plan.viz.replay_plot import plot_replay

        plot_replay(result, cumulative_J(rec, result.recorded_W),
                    cumulative_J(rec, result.predicted_W), png,
                    title=f"{recording.name} under {ctx.scenario.name}")
        report["png"] = str(png)
    if as_json:
        print_json(report)
        return
    wh = 1.0 / 3600.0
    out.print(f"{recording} under {ctx.scenario.name}: {result.duration_s:,.1f} s")
    out.print(f"  recorded  {result.energy_recorded_J * wh:,.3f} Wh")
    out.print(f"  predicted {result.energy_predicted_J * wh:,.3f} +- "
              f"{result.energy_predicted_sd_J * wh:,.3f} Wh ({result.energy_error_pct:+.1f} %), "
              f"power RMSE {result.rmse_W:,.1f} W")
    for issue in rec.issues:
        out.print(f"  {issue}", markup=False, highlight=False, soft_wrap=True)
    if png is not None:
        out.print(f"  figure: {png}")
