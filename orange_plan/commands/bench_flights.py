"""``orange-plan bench flights``: predicted against recorded energy of real DJI Matrice 100
survey flights, from the recording and from the planned route alone (docs/m100.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from orange_plan.cli import JsonOpt, bench_app, handles_errors, out, print_json
from orange_plan.progress import bar, wanted

DataOpt = Annotated[Path | None, typer.Option(
    "--data", help="Folder holding the wadl_m100/ flights (not shipped with the package; "
                   "default: the first of ./data, ../shared/data and "
                   "<prefix>/share/orange-plan/data that exists).")]
ScenarioOpt = Annotated[Path | None, typer.Option(
    "--scenario", help="Scenario TOML (default: the shipped scenarios/dji_m100.toml).")]
SCENARIO = "dji_m100.toml"
LimitOpt = Annotated[int | None, typer.Option(
    "--limit", min=2, help="Use only the first N flights (sorted by name).")]
PngOpt = Annotated[Path | None, typer.Option(
    "--png", help="Figure: each method's error per flight, the transit-speed flights marked.")]
DiagnoseOpt = Annotated[int, typer.Option(
    "--diagnose", min=0, help="Also run diagnose with the a-priori scenario on the first N "
                              "nominal flights and count what it finds.")]


@bench_app.command("flights")
@handles_errors
def bench_flights_cmd(data: DataOpt = None, scenario: ScenarioOpt = None, limit: LimitOpt = None,
                    png: PngOpt = None, diagnose: DiagnoseOpt = 0,
                    as_json: JsonOpt = False) -> None:
    """Leave-one-route-out: each flight's energy from its recording, from its planned route,
    by energy per metre x planned length and by mean power x planned time."""
    from orange_plan.bench.flights import (
        DATASET,
        check_benchmark,
        diagnose_flights,
        flight_paths,
        load_flight,
        summarise,
    )
    from orange_plan.context import load_context
    from orange_plan.examples import examples_dir
    from orange_plan.files import check_output, require_folder

    if png is not None:
        check_output(png, "--png", [".png"])
    folder = (data if data is not None else examples_dir("data", "--data")) / DATASET
    require_folder(folder, "--data")
    ctx = load_context(scenario or _shipped_scenario())
    paths = flight_paths(folder, limit)
    with bar(len(paths), "flights", wanted(as_json)) as tick:
        flights = []
        for p in paths:
            flights.append(load_flight(p))
            if tick:
                tick()
    routes = len({f.route for f in flights})
    with bar(routes, "folds", wanted(as_json)) as tick:
        rows = check_benchmark(flights, ctx, progress=tick)
    summary = summarise(rows)
    if diagnose:
        summary["diagnose"] = diagnose_flights(flights, ctx, diagnose)
    if png is not None:
        from orange_plan.viz.flights_plot import plot_check

        plot_check(rows, png)
        summary["png"] = str(png)
    if as_json:
        print_json({"summary": summary, "flights": rows})
        return
    _print(summary)


def _shipped_scenario() -> Path:
    """The first ``dji_m100.toml`` of the example folders (examples' look-up order)."""
    from orange_plan.errors import InputError
    from orange_plan.examples import candidate_dirs, looked_in

    for folder in candidate_dirs("scenarios"):
        if (folder / SCENARIO).is_file():
            return folder / SCENARIO
    raise InputError(f"{SCENARIO} not found (looked in {looked_in('scenarios')}); give "
                     "--scenario")


def _print(summary: dict) -> None:
    table = Table(title=f"WADL M100: {summary['nominal']} nominal flights, "
                        f"{summary['folds']} routes left out in turn")
    for col in ("method", "median |error| %", "median error %", "CURVED", "NORMAL"):
        table.add_column(col, justify="right")
    by_mode = summary["median_abs_err_pct_by_fly_mode"]
    for method, value in summary["median_abs_err_pct"].items():
        table.add_row(method, f"{value:.1f}", f"{summary['median_err_pct'][method]:+.1f}",
                      *(f"{by_mode[m][method]:.1f}" if m in by_mode else "-"
                        for m in ("CURVED", "NORMAL")))
    out.print(table)
    for name, ok in summary["targets"].items():
        out.print(f"  target {name}: {'met' if ok else 'NOT met'}")
    for p, cov in summary["reserve"].items():
        out.print(f"  reserve p = {p}: {cov['exceeded']} of {cov['flights']} flights exceed "
                  f"route + reserve ({cov['exceeded_pct']:.1f} %, allowed "
                  f"{cov['allowed_pct']:.0f} %); folds with an exceedance "
                  f"{cov['folds_with_exceedance']} of {cov['folds']}")
    for a in summary["speed_anomalies"]:
        out.print(f"  transit-speed flight {a['flight']} ({a['route']}): route "
                  f"{a['route_err_pct']:+.1f} %, recording {a['recording_err_pct']:+.1f} %")
    if "diagnose" in summary:
        d = summary["diagnose"]
        out.print(f"  diagnose on {d['flights']} flights: " + (", ".join(
            f"{k} x{v}" for k, v in d["found"].items()) or "nothing found"))
