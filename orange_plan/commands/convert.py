"""``orange-plan convert``: import a robot log into a recording."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from orange_plan.cli import JsonOpt, app, handles_errors, out, print_json, progress_console

LogArg = Annotated[Path, typer.Argument(
    help="Robot log: PX4 .ulg, ROS 1 .bag, ROS 2 bag (folder, .db3, .mcap), BorealTC "
         "pro_NN.csv, TUM BMW i3 TripAxx.csv.gz, WADL DJI M100 flight <id>.csv (its "
         ".route.csv, .wp_events.csv and .json beside it).")]
FormatOpt = Annotated[str | None, typer.Option(
    "--format", help="ulog, rosbag1, rosbag2, borealtc, tum_bmw_i3 or wadl (default: guessed).")]
OutOpt = Annotated[Path, typer.Option("-o", "--output", help="Recording to write (.csv or .parquet).")]


@app.command("convert")
@handles_errors
def convert_cmd(log: LogArg, output: OutOpt, fmt: FormatOpt = None,
                as_json: JsonOpt = False) -> None:
    """Import a robot log into a recording table (t_s, power_W, x_m, y_m, ...), checked and
    completed."""
    from orange_plan.files import check_output
    from orange_plan.progress import stages
    from orange_plan.telemetry.importers import read_log
    from orange_plan.telemetry.recording import (
        recording_extension,
        recording_from_frame,
        write_recording,
    )

    check_output(output, "-o", inputs=[log])  # before the (possibly long) import
    recording_extension(output)
    with stages(progress_console(as_json)) as step:
        step(f"reading {log.name}")
        frame, used = read_log(log, fmt)
        step(f"checking {len(frame):,} rows")
        recording = recording_from_frame(frame, source=str(log))
        step(f"writing {output.name}")
        write_recording(recording, output)
    report = {
        "format": used,
        "input": str(log),
        "output": str(output),
        "rows": len(recording.frame),
        "columns": list(recording.frame.columns),
        "duration_s": recording.duration_s,
        "energy_J": recording.energy_J,
        "distance_m": recording.distance_m,
        "issues": [i.to_dict() for i in recording.issues],
    }
    if as_json:
        print_json(report)
        return
    out.print(f"{used}: {log} -> {output}: {report['rows']} rows, "
              f"{recording.duration_s:,.1f} s, {recording.energy_J / 3600:,.2f} Wh, "
              f"{recording.distance_m:,.1f} m", soft_wrap=True)
    for issue in recording.issues:
        out.print(f"  {issue}", markup=False, highlight=False, soft_wrap=True)
