"""``orange-plan bench watch``: do the watch's decisions follow 10 Hz telemetry in time?"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from orange_plan.cli import JsonOpt, bench_app, check_range, handles_errors, out, print_json


@bench_app.command("watch")
@handles_errors
def bench_watch_cmd(
    scenario: Annotated[Path | None, typer.Argument(
        help="Scenario TOML over the drone field (default: scenarios/ar_drone_wind.toml).")]
    = None,
    duration_s: Annotated[float, typer.Option(
        "--duration-s", help="Wall seconds of flight watched.")] = 60.0,
    rate_hz: Annotated[float, typer.Option(
        "--rate-hz", help="Telemetry rate [Hz].")] = 10.0,
    speedup: Annotated[float, typer.Option(
        "--speedup", help="Simulated seconds per wall second (1: real time).")] = 1.0,
    as_json: JsonOpt = False,
) -> None:
    """Fly a simulated vehicle on 127.0.0.1 with a watch reading it, and measure how long
    each decision lags the telemetry it covers (median, p95, max) against 200 ms."""
    from orange_plan.context import load_context
    from orange_plan.examples import examples_dir
    from orange_plan.service.watch_bench import TARGET_S, run_watch_bench

    check_range(duration_s, "--duration-s", high=3600.0)
    ctx = load_context(scenario or examples_dir("scenarios", "a SCENARIO argument")
                       / "ar_drone_wind.toml")
    result = run_watch_bench(ctx, duration_s, rate_hz, speedup)
    if as_json:
        print_json({"scenario": ctx.scenario.name, **result})
        return
    out.print(f"{result['decisions']} decisions at {rate_hz:g} Hz x{speedup:g}: lag median "
              f"{result['lag_median_s'] * 1000:.0f} ms, p95 {result['lag_p95_s'] * 1000:.0f} ms,"
              f" max {result['lag_max_s'] * 1000:.0f} ms; "
              f"{result['within_target']:.1%} within {TARGET_S * 1000:.0f} ms "
              f"({'met' if result['meets_target'] else 'NOT met'})")
