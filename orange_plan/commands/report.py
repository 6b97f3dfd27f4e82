"""``orange-plan report paper``: the ORangE paper's validation, regenerated."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from orange_plan.cli import JsonOpt, app, handles_errors, out, print_json, progress_console
from orange_plan.commands.bench_identify import DataOpt, ScenariosOpt, _scenarios
from orange_plan.errors import InputError
from orange_plan.files import check_output, require_folder
from orange_plan.progress import bar

report_app = typer.Typer(no_args_is_help=True, help="Reports regenerated from one command.")
app.add_typer(report_app, name="report")

DEFAULT_TRIALS = 10


@report_app.command("paper")
@handles_errors
def paper_cmd(
    out_dir: Annotated[Path, typer.Option("-o", "--out", help="Folder for report.md, "
                                          "report.json and the PNG figures.")],
    trials: Annotated[int, typer.Option(help="Simulated trials per experiment cell (>= 2).")]
    = DEFAULT_TRIALS,
    seed: Annotated[int, typer.Option(help="Seed of every truth draw and run.")] = 0,
    data: DataOpt = None,
    scenarios: ScenariosOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Regenerate the paper's experiments (Rusti V1.0, Rusti V2.0, AR Drone), their real-data
    counterparts and the wear-and-tear study as a markdown report with PNG figures."""
    from orange_plan.report.paper import generate, total_items

    if trials < 2:
        raise InputError(f"--trials = {trials} must be >= 2 (a standard deviation needs two)")
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"-o {out_dir}: exists and is not a folder")
    check_output(out_dir / "report.md", "-o")  # the folder can be made and written
    if data is not None:
        require_folder(data, "--data")
    else:
        from orange_plan.examples import find_dir

        data = find_dir("data")
    scenarios = _scenarios(scenarios)
    with bar(total_items(trials, data), "report paper: runs", progress_console(as_json)) as tick:
        summary = generate(out_dir, scenarios, data, trials, seed, tick)
    if as_json:
        print_json(summary | {"out": str(out_dir)})
        return
    out.print(_headline(summary))
    if data is None:
        from orange_plan.report.paper import missing_data_note

        out.print(f"section 5 (real data) not run: {missing_data_note()}", markup=False)
    out.print(f"report: {out_dir / 'report.md'} ({len(summary['files']) - 2} figures, "
              f"{summary['elapsed_s']:.0f} s)")


def _headline(summary: dict) -> Table:
    """The headline numbers: ours beside the paper's."""
    sec = summary["sections"]
    table = Table(title=f"ORangE paper, regenerated ({summary['trials']} trials)",
                  header_style="bold")
    for col in ("experiment", "ours", "paper"):
        table.add_column(col)
    v1 = [100 - c["error_prior_pct"] for c in sec["rusti_v1"]["cells"]]
    v1c = [100 - c["error_calibrated_pct"] for c in sec["rusti_v1"]["cells"]]
    table.add_row("Rusti V1.0 accuracy, a priori (calibrated)",
                  f"{min(v1):.0f}-{max(v1):.0f} % ({min(v1c):.0f}-{max(v1c):.0f} %)", "66-91 %")
    v2 = [100 - c["error_prior_pct"] for c in sec["rusti_v2"]["cells"]]
    v2c = [100 - c["error_calibrated_pct"] for c in sec["rusti_v2"]["cells"]]
    table.add_row("Rusti V2.0 accuracy, a priori (calibrated)",
                  f"{min(v2):.0f}-{max(v2):.0f} % ({min(v2c):.0f}-{max(v2c):.0f} %)",
                  "figure only")
    for cell in sec["ar_drone"]["cells"]:
        paper = sec["ar_drone"]["paper_pct"]
        table.add_row(f"AR Drone offline / online, from {cell['model']}",
                      f"{cell['accuracy_offline_pct']:.1f} / {cell['accuracy_online_pct']:.1f} %",
                      f"{paper['offline']:.2f} / {paper['online']:.2f} %"
                      if cell["model"] == "a priori" else "-")
    for ds, rows in (sec["real_data"] or {}).items():
        every = rows[-1]  # the "all" group
        table.add_row(f"{ds}: accuracy on own path, a priori / calibrated / online",
                      " / ".join(f"{v:.0f}" for k, v in every.items()
                                 if k not in ("group", "runs")) + " %", "no counterpart")
    last = sec["wear"]["missions"][-1]
    table.add_row(f"wear: error at mission {last['mission']} (stale / re-est. / online)",
                  " / ".join(f"{last[k]:.1f}" for k in last if k not in ("mission", "d_true_m"))
                  + " %", "future work")
    return table
