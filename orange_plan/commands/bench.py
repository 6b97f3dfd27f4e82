"""``orange-plan bench``: benchmarks (``bench reach``: the planning core: roadmap, reach, speeds)."""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from orange_plan.cli import (
    JsonOpt,
    bench_app,
    default_scenario,
    handles_errors,
    out,
    print_json,
    progress_console,
)
from orange_plan.errors import InputError
from orange_plan.progress import stages

TARGETS = {"roadmap_s": 2.5, "queries_s": 1.0, "roadmap_vs_grid": 1.03, "speed_1000_warm_s": 0.1,
           "saving_vs_shortest": 0.20}


@bench_app.command("reach")
@handles_errors
def bench_reach_cmd(
    scenario: Annotated[Path | None, typer.Argument(
        help="Scenario TOML (default: the hilly example, scenarios/kiwibot_campus.toml).")] = None,
    repeats: Annotated[int, typer.Option(help="Repeats per timing (median reported).")] = 3,
    vertices: Annotated[int, typer.Option(help="Roadmap vertices.")] = 5000,
    bitstar_s: Annotated[float, typer.Option(
        "--bitstar-s", help="BIT* refinement budget per pair [s] (0: skip).")] = 1.0,
    as_json: JsonOpt = False,
) -> None:
    """Roadmap/field build time, goal-query throughput, path energy vs a dense-grid
    reference and vs the shortest path, and speed-optimiser times."""
    from orange_plan.bench.reach import run_reach_bench
    from orange_plan.context import load_context

    scenario = scenario or default_scenario()
    if repeats < 1:
        raise InputError(f"--repeats = {repeats} must be >= 1")
    with stages(progress_console(as_json)) as step:
        ctx = load_context(scenario)
        result = run_reach_bench(ctx, repeats=repeats, n_vertices=vertices,
                                 bitstar_seconds=bitstar_s, step=step)
    if as_json:
        print_json(result.to_dict())
        return
    out.print(bench_table(result))


def bench_table(r) -> Table:
    """The benchmark table (docs/benchmarks/): measured value, target, and a ratio that is <= 1 when the target is
    met (measured/target for upper limits, target/measured for lower limits; worst pair for the
    grid comparison)."""
    t = Table(title=f"bench reach: {r.scenario} (median of {r.repeats})", header_style="bold")
    for col in ("measure", "measured", "target", "ratio"):
        t.add_column(col, justify="left" if col == "measure" else "right")
    ratio = statistics.median(p.roadmap_vs_grid for p in r.pairs)
    worst = max(p.roadmap_vs_grid for p in r.pairs)
    saving = r.pairs[0].saving_vs_shortest
    t.add_row(f"roadmap {r.n_vertices} vertices, {r.n_edges} edges + weights + 2 fields",
              f"{r.roadmap_s:.2f} s", f"<= {TARGETS['roadmap_s']} s",
              f"{r.roadmap_s / TARGETS['roadmap_s']:.2f}")
    t.add_row(f"{r.goal_queries} goal queries", f"{r.queries_s:.3f} s",
              f"<= {TARGETS['queries_s']} s", f"{r.queries_s / TARGETS['queries_s']:.2f}")
    t.add_row(f"roadmap energy / grid reference ({r.grid_cell_m:g} m, 16-conn.), median of "
              f"{len(r.pairs)} pairs (worst)", f"{ratio:.3f} ({worst:.3f})", "<= 1.03",
              f"{worst / TARGETS['roadmap_vs_grid']:.2f}")
    bits = [p.bitstar_J / p.grid_J for p in r.pairs if p.bitstar_J is not None]
    if bits:
        t.add_row(f"BIT* {r.bitstar_seconds:g} s alone / grid reference, median",
                  f"{statistics.median(bits):.3f}", "(not a target)", "")
    a, b = r.pairs[0].start_xy_m, r.pairs[0].goal_xy_m
    t.add_row(f"energy saved vs shortest path, ({a[0]:g}, {a[1]:g}) -> ({b[0]:g}, {b[1]:g}) m",
              f"{saving:.1%}", ">= 20 %",
              f"{TARGETS['saving_vs_shortest'] / max(saving, 1e-9):.2f}")
    t.add_row("energy saved vs shortest path, all pairs (min..max)",
              f"{min(p.saving_vs_shortest for p in r.pairs):.1%}.."
              f"{max(p.saving_vs_shortest for p in r.pairs):.1%}", "", "")
    for n, s in r.speed_s.items():
        target = f"<= {TARGETS['speed_1000_warm_s'] * 1e3:.0f} ms" if n == 1000 else ""
        ratio_txt = f"{s['warm_s'] / TARGETS['speed_1000_warm_s']:.2f}" if n == 1000 else ""
        t.add_row(f"speed profile N = {n} warm (cold incl. build), {s['iterations']} IPOPT it.",
                  f"{s['warm_s'] * 1e3:.1f} ms ({s['cold_s'] * 1e3:.0f} ms)", target, ratio_txt)
    t.add_row(f"dense-grid reference build ({r.grid_cell_m:g} m)", f"{r.grid_s:.1f} s", "", "")
    return t


DEFAULT_PLAN_SCENARIOS = "kiwibot_campus,ar_drone_wind,marine_survey,husky_a200,random"


def check_outputs(png: Path | None, out_file: Path | None) -> None:
    """A benchmark's --png and --out, checked before its minutes of work."""
    from orange_plan.files import check_output

    if png is not None:
        check_output(png, "--png", [".png"])
    if out_file is not None:
        check_output(out_file, "--out", [".json"], inputs=[png])


@bench_app.command("plan")
@handles_errors
def bench_plan_cmd(
    scenarios: Annotated[str, typer.Option(
        help="Comma-separated shipped scenario names or .toml paths; 'random' = the generated "
             "family.")] = DEFAULT_PLAN_SCENARIOS,
    seeds: Annotated[int | None, typer.Option(
        help="Truths (simulated flights) per scenario and method (default 20; 2 with --quick).")] = None,
    quick: Annotated[bool, typer.Option(
        help="Small run for tests: the random family of one small map, 2 seeds, no 2 km map.")] = False,
    vertices: Annotated[int, typer.Option(help="Roadmap vertices of the planners.")] = 5000,
    family_size: Annotated[int, typer.Option(help="Maps in the random family.")] = 4,
    large: Annotated[bool, typer.Option(
        help="Time (c) on the generated 2 km x 2 km map (300 obstacles, DEM).")] = True,
    png: Annotated[Path | None, typer.Option(help="PNG: coverage vs strandings per method.")] = None,
    confidence: Annotated[float, typer.Option(
        help="Reserve of the planners (b) and (c): confidence = p (0: each scenario's own "
             "reserve rule).")] = 0.95,
    out_file: Annotated[Path | None, typer.Option(
        "--out", help="Write the JSON result here after each scenario (partial) and at the end.")] = None,
    planner: Annotated[str, typer.Option(
        help="Tour planner MODULE:FUNCTION for (b) and (c).")] = "orange_plan.planning.tour:plan_tour",
    as_json: JsonOpt = False,
) -> None:
    """Coverage with a guaranteed return: (a) lawnmower + PX4 return rule, (b) the planner
    with a distance budget, (c) the planner; flown under truths within the calibration
    uncertainty."""
    import functools
    import json
    import tempfile

    from orange_plan.atomic import atomic_path
    from orange_plan.bench.plan import (
        at_confidence,
        plan_figure,
        plan_table,
        run_plan_bench,
        scenario_specs,
    )

    seeds = seeds if seeds is not None else (2 if quick else 20)
    check_outputs(png, out_file)
    if family_size < 1:
        raise InputError(f"--family-size = {family_size} must be >= 1")
    names = [s.strip() for s in scenarios.split(",") if s.strip()]
    if quick and scenarios == DEFAULT_PLAN_SCENARIOS:
        names = ["random"]
    if not 0 <= confidence < 1:
        raise InputError(f"--confidence = {confidence:g} must be in (0, 1), or 0 for each "
                         "scenario's own reserve")
    plan_fn = at_confidence(functools.partial(load_planner(planner),
                                              n_vertices=800 if quick else vertices, seed=0),
                            confidence or None)

    def save(result) -> None:
        if out_file is not None:
            with atomic_path(out_file, suffix=".json") as tmp:
                tmp.write_text(json.dumps(result.to_dict(), indent=1), encoding="utf-8")

    with tempfile.TemporaryDirectory(prefix="orange-bench-plan-") as folder, \
            stages(progress_console(as_json)) as step:
        specs = scenario_specs(names, Path(folder), 1 if quick else family_size,
                               {"width_m": 80.0, "height_m": 60.0} if quick else None)
        result = run_plan_bench(specs, plan_fn, seeds, n_vertices=800 if quick else 3000,
                                large_folder=None if quick or not large else Path(folder) / "large",
                                step=step, on_progress=save)
    save(result)
    if png is not None:
        plan_figure(result, png)
    if as_json:
        print_json(result.to_dict())
        return
    out.print(plan_table(result))
    if png is not None:
        out.print(f"wrote {png}")


def load_planner(spec: str):
    """``MODULE:FUNCTION`` -> the function (InputError naming the spec if it is missing)."""
    import importlib

    module, _, name = spec.partition(":")
    try:
        fn = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise InputError(f"--planner {spec}: not available ({exc})") from None
    if not callable(fn):
        raise InputError(f"--planner {spec}: not a function")
    return fn


@bench_app.command("service")
@handles_errors
def bench_service_cmd(
    seconds: Annotated[float, typer.Option(help="Timed load per repeat [s].")] = 20.0,
    repeats: Annotated[int, typer.Option(help="Repeats (medians reported).")] = 3,
    robots: Annotated[int, typer.Option(help="Missions posting telemetry at once.")] = 20,
    batch: Annotated[int, typer.Option(help="Samples per telemetry batch.")] = 50,
    rate: Annotated[float, typer.Option(help="Samples/s offered by all robots together.")]
        = 2000.0,
    vertices: Annotated[int, typer.Option(help="Roadmap vertices of each mission.")] = 300,
    as_json: JsonOpt = False,
) -> None:
    """Telemetry throughput and POST latency of one `orange-plan serve` (a subprocess on
    127.0.0.1, a temporary database) under a paced fleet of robots."""
    from orange_plan.bench.service_load import run_service_bench, service_table

    for name, value, low in (("--seconds", seconds, 1.0), ("--repeats", repeats, 1),
                             ("--robots", robots, 1), ("--batch", batch, 1),
                             ("--rate", rate, 1.0), ("--vertices", vertices, 50)):
        if not value >= low:
            raise InputError(f"{name} = {value} must be >= {low}")
    with stages(progress_console(as_json)) as step:
        result = run_service_bench(seconds=seconds, repeats=repeats, robots=robots,
                                   batch=batch, rate=rate, n_vertices=vertices, step=step)
    if as_json:
        print_json(result.to_dict())
        return
    out.print(service_table(result))


@bench_app.command("mission")
@handles_errors
def bench_mission_cmd(
    missions: Annotated[int | None, typer.Option(
        help="Simulated missions (default 500; 3 with --quick).")] = None,
    seed: Annotated[int, typer.Option(help="Seed of the first mission's truth.")] = 0,
    maps: Annotated[int, typer.Option(help="Maps of the random family flown in turn.")] = 10,
    vertices: Annotated[int, typer.Option(help="Roadmap vertices of every planner.")] = 1000,
    workers: Annotated[int, typer.Option(
        help="Worker processes of the local Dask cluster flying missions at once.")] = 2,
    scheduler: Annotated[str | None, typer.Option(
        help="Address tcp://HOST:PORT of an existing Dask scheduler to fly the missions on "
             "instead (as `orange-plan sweep --scheduler`).")] = None,
    quick: Annotated[bool, typer.Option(
        help="Small run for tests: 3 missions on one 80 m x 60 m map, 400 vertices, 1 process.")]
        = False,
    png: Annotated[Path | None, typer.Option(help="PNG: coverage vs strandings.")] = None,
    out_file: Annotated[Path | None, typer.Option(
        "--out", help="Write the JSON result here every 10 missions (partial) and at the end.")]
        = None,
    as_json: JsonOpt = False,
) -> None:
    """Monte Carlo missions under truths within and beyond the calibration uncertainty:
    (a) the session with replanning, (b) the first plan open loop, (c) a lawnmower with the
    PX4-style return rule, (d) the oracle plan made with the true model."""
    import json

    from orange_plan.atomic import atomic_path
    from orange_plan.bench.mission import mission_figure, mission_table, run_mission_study
    from orange_plan.progress import bar

    missions = missions if missions is not None else (3 if quick else 500)
    check_outputs(png, out_file)
    kwargs = {"n_vertices": 400 if quick else vertices}
    if quick:
        kwargs |= {"width_m": 80.0, "height_m": 60.0}
        maps, workers = 1, 1

    def save(result) -> None:
        if out_file is not None:
            with atomic_path(out_file, suffix=".json") as tmp:
                tmp.write_text(json.dumps(result, indent=1), encoding="utf-8")

    with bar(missions, "missions", progress_console(as_json)) as tick:
        result = run_mission_study(missions, seed, maps, workers, kwargs, tick=tick,
                                   on_progress=save, scheduler=scheduler)
    save(result)
    if png is not None:
        mission_figure(result, png)
    if as_json:
        print_json(result)
        return
    out.print(mission_table(result))
    ratio = result["session_over_oracle"]
    out.print(f"session / oracle coverage: {'-' if ratio is None else format(ratio, '.2f')} "
              f"(target >= 0.85); {result['runtime_s']:.0f} s")
    if png is not None:
        out.print(f"wrote {png}")
