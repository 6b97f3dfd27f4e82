"""One sweep run on a worker: plan a tour, fly it in the simulator, score it (one row).

The scoring is ``sim.flight.fly_open_loop``'s (the first tour flown as planned): coverage is
the sensed area up to the battery's exhaustion, a run is stranded when the true energy drawn
exceeds the truth's usable energy before home or when it does not end home.
"""

from __future__ import annotations

import json
import os
import socket
import time
from datetime import UTC, datetime
from pathlib import Path

from orange_plan.context import Context, context_of
from orange_plan.errors import InputError, OrangeError
from orange_plan.planning.tour import plan_tour
from orange_plan.scenario import scenario_from_dict
from orange_plan.sim.flight import fly_open_loop
from orange_plan.sim.perturb import calibration_truths
from orange_plan.sim.truth import Truth, truth_from_dict
from orange_plan.sweep.spec import RunSpec

RESULT_COLUMNS = ("coverage_m2", "planned_coverage_m2", "energy_available_J",
                  "energy_planned_J", "energy_left_J", "stranded", "duration_s", "planned",
                  "note", "error", "plan_s", "fly_s", "run_s")
"""Outcome and timing columns of a row (besides the run's inputs)."""


def run_one(run: RunSpec) -> dict:
    """Plan, simulate and score one run; a pure function of ``run`` but for the timings.

    A planner refusal (no tour fits the battery) is an outcome: the robot stays home
    (``planned`` False, coverage 0, not stranded). Any other orange-plan error is recorded in
    ``error`` with empty outcome columns; a bug is raised (the sweep stops, finished rows kept).
    """
    from orange_plan import __version__

    t0 = time.perf_counter()
    row = _inputs(run)
    try:
        row |= _plan_fly_score(run)
    except OrangeError as exc:
        row |= {"error": f"{type(exc).__name__}: {exc}"}
    row["run_s"] = time.perf_counter() - t0
    row |= {"worker": f"{socket.gethostname()}:{os.getpid()}", "version": __version__,
            "finished_utc": datetime.now(UTC).isoformat(timespec="milliseconds")}
    return {c: row.get(c) for c in (*_inputs(run), *RESULT_COLUMNS, "worker", "version",
                                    "finished_utc")}


def _inputs(run: RunSpec) -> dict:
    truth = run.truth if isinstance(run.truth, str) else "TRUTH.toml"
    return {"run_id": run.run_id, "index": run.index, "scenario": run.scenario,
            "scenario_file": run.scenario_file, **{k: _cell(v) for k, v in run.params},
            "seed": run.seed,
            "truth": truth, "vertices": run.n_vertices, "sample_rate_Hz": run.sample_rate_Hz}


def _cell(value):
    """A grid value as a Parquet cell: an inline table (``{fraction = 0.1}``) as its JSON."""
    return json.dumps(value, sort_keys=True) if isinstance(value, dict) else value


def _plan_fly_score(run: RunSpec) -> dict:
    ctx = context_of(scenario_from_dict(run.scenario_data, Path(run.scenario_file)))
    truth = _truth(ctx, run)
    usable_J = ctx.scenario.battery.usable_J * truth.capacity_factor
    t0 = time.perf_counter()
    try:
        plan = plan_tour(ctx, n_vertices=run.n_vertices, seed=run.seed, bitstar_legs=0)
    except InputError as exc:
        return {"coverage_m2": 0.0, "planned_coverage_m2": 0.0, "energy_available_J": usable_J,
                "energy_planned_J": 0.0, "energy_left_J": usable_J, "stranded": False,
                "duration_s": 0.0, "planned": False, "note": f"stayed home: {exc}",
                "plan_s": time.perf_counter() - t0, "fly_s": 0.0}
    t1 = time.perf_counter()
    flown = fly_open_loop(ctx, plan, truth, run.seed, run.sample_rate_Hz)
    return {"coverage_m2": flown["coverage_m2"],
            "planned_coverage_m2": float(plan.summary["coverage_m2"]),
            "energy_available_J": usable_J,
            "energy_planned_J": float(plan.summary["energy_planned_J"]),
            "energy_left_J": flown["energy_left_J"], "stranded": flown["stranded"],
            "duration_s": flown["duration_s"], "planned": True, "note": "",
            "plan_s": t1 - t0, "fly_s": time.perf_counter() - t1}


def _truth(ctx: Context, run: RunSpec):
    if run.truth == "calibration":
        return calibration_truths(ctx, 1, seed=run.seed)[0]
    if run.truth == "model":
        return Truth()
    return truth_from_dict(run.truth, "truth")
