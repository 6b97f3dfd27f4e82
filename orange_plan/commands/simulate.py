"""``orange-plan simulate``: drive a plan (or route CSV) under a truth model, write a recording."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from orange_plan.cli import (
    MAX_TIME_S,
    JsonOpt,
    ScenarioArg,
    app,
    check_range,
    handles_errors,
    out,
    print_json,
)

PlanArg = Annotated[Path, typer.Argument(
    help="Plan GeoJSON (its LineString feature of kind 'tour', with per-vertex speed_mps) or "
         "route CSV (x_m, y_m[, speed_mps]).")]
OutOpt = Annotated[Path, typer.Option("-o", "--output", help="Recording to write (.csv or .parquet).")]
TruthOpt = Annotated[Path | None, typer.Option(
    "--truth", help="TRUTH.toml: truth-only effects (wind gusts, payload, roughness, ageing, "
                    "noise, coefficient overrides).")]
SeedOpt = Annotated[int, typer.Option("--seed", help="Random seed (gusts, roughness, noise).")]
RateOpt = Annotated[float, typer.Option("--rate-hz", help="Sample rate of the recording [Hz].")]
DepleteOpt = Annotated[bool, typer.Option(
    "--to-depletion", help="Repeat the route (closed, else out and back) until the battery's "
                           "true usable energy is spent.")]
MaxOpt = Annotated[float, typer.Option("--max-duration-s", help="Stop after this mission time, in seconds.")]


@app.command("simulate")
@handles_errors
def simulate_cmd(scenario: ScenarioArg, plan: PlanArg, output: OutOpt, truth: TruthOpt = None,
                 seed: SeedOpt = 0, rate_hz: RateOpt = 10.0, to_depletion: DepleteOpt = False,
                 max_duration_s: MaxOpt = 172_800.0, as_json: JsonOpt = False) -> None:
    """Fly/drive a plan in the simulator (scenario model + truth effects); write a recording.

    Speeds are clipped to the robot's v_min_mps..v_max_mps; clipped vertices are counted.
    """
    from orange_plan.context import load_context
    from orange_plan.files import check_output
    from orange_plan.sim.route import load_route
    from orange_plan.sim.simulator import simulate
    from orange_plan.sim.truth import load_truth
    from orange_plan.telemetry.recording import recording_extension, write_recording

    check_range(max_duration_s, "--max-duration-s", high=MAX_TIME_S)
    check_output(output, "-o", inputs=[scenario, plan, truth])  # before the work
    recording_extension(output)
    ctx = load_context(scenario)
    result = simulate(ctx, load_route(plan), load_truth(truth), seed=seed,
                      sample_rate_Hz=rate_hz, to_depletion=to_depletion,
                      max_duration_s=max_duration_s)
    write_recording(result.frame, output)
    report = {"scenario": ctx.scenario.name, "recording": str(output), **result.summary()}
    if as_json:
        print_json(report)
        return
    out.print(f"{output}: {report['samples']} samples, {result.duration_s:,.1f} s, "
              f"{result.distance_m:,.1f} m, {result.energy_J / 3600:,.3f} Wh"
              + (" (battery depleted)" if result.depleted else ""))
    if result.speeds_clipped:
        robot = ctx.scenario.robot
        out.print(f"note: {result.speeds_clipped} route speed(s) outside the robot's "
                  f"[{robot.v_min_mps:g}, {robot.v_max_mps:g}] m/s were clipped to it",
                  highlight=False)
