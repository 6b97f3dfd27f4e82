"""Benchmarks of ``orange-plan sweep`` (targets).

``run_speedup_bench``: one fixed sweep (a shipped scenario, one run per seed) computed on a
local Dask cluster of 1 and of 2 workers, alternately, ``repeats`` times. Each cluster is
started and its workers warmed (the planner's modules imported) before the clock starts, so
the time is the sweep's: first submission to last row stored. Speed-up = median time with 1
worker / median time with 2.

``busy`` is the workers' time spent in runs over their wall time (sum of ``run_s`` / (workers
x sweep time)): near 1, Dask adds little and the speed-up is what the cores give; the run time
with 2 workers over that with 1 shows how much the two workers slowed each other down (a
machine with other work on it: fewer free cores than workers).

``run_resume_check``: a sweep of ``runs`` runs started as its own process (``orange-plan
sweep``), killed with SIGKILL, with its scheduler and workers, once ``kill_after`` rows are
stored; then run again. It must end with exactly ``runs`` rows, one per run id, the rows
stored before the kill untouched, and no process of the killed sweep left.
"""

from __future__ import annotations

import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import tomli_w

from orange_plan.cluster import dask_client, run_tasks
from orange_plan.sweep.spec import load_sweep
from orange_plan.sweep.store import ResultStore
from orange_plan.sweep.task import run_one

TARGETS = {"speedup_1_to_2": 1.7, "resume_rows": 200}


def _warm() -> None:
    """Import what a run needs, on a worker, before the clock starts."""
    import orange_plan.bench.mission
    import orange_plan.planning.tour
    import orange_plan.sweep.task  # noqa: F401


def write_seed_sweep(folder: Path, scenario: Path, runs: int, vertices: int,
                     name: str = "bench") -> Path:
    """A sweep of ``scenario`` alone, ``runs`` seeds, no grid."""
    path = folder / f"{name}.toml"
    path.write_text(tomli_w.dumps({"name": name, "scenarios": [str(scenario.resolve())],
                                   "seeds": runs, "vertices": vertices}), encoding="utf-8")
    return path


def run_speedup_bench(scenario: Path, runs: int = 12, repeats: int = 3, vertices: int = 1000,
                      step: Callable[[str], None] | None = None) -> dict:
    """Time the sweep with 1 and 2 local workers (module docstring); return the figures."""

    step = step or (lambda text: None)
    times: dict[int, list[float]] = {1: [], 2: []}
    busy: dict[int, list[float]] = {1: [], 2: []}
    run_s: dict[int, list[float]] = {1: [], 2: []}
    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory(prefix="orange-bench-sweep-") as folder:
        sweep = load_sweep(write_seed_sweep(Path(folder), scenario, runs, vertices))
        for rep in range(repeats):
            for workers in (1, 2):
                step(f"repeat {rep + 1}/{repeats}: {workers} worker(s)")
                store = ResultStore(Path(folder) / f"r{rep}w{workers}.parquet")
                with dask_client(workers) as client:
                    client.run(_warm)
                    t0 = time.perf_counter()
                    run_tasks(client, run_one, [(r.run_id, (r,)) for r in sweep.runs],
                              lambda _key, row, store=store: store.add(row))
                    times[workers].append(time.perf_counter() - t0)
                rows = store.consolidate()
                run_s[workers] += list(rows["run_s"])
                busy[workers].append(float(rows["run_s"].sum()) / (workers * times[workers][-1]))
                load.append(os.getloadavg()[0])
    t1, t2 = statistics.median(times[1]), statistics.median(times[2])
    return {"scenario": scenario.stem, "runs": runs, "repeats": repeats, "vertices": vertices,
            "seconds_1_worker": times[1], "seconds_2_workers": times[2],
            "median_1_worker_s": t1, "median_2_workers_s": t2, "speedup": t1 / t2,
            "median_run_s": statistics.median(run_s[1]),
            "median_run_s_2_workers": statistics.median(run_s[2]),
            "busy_1_worker": statistics.median(busy[1]),
            "busy_2_workers": statistics.median(busy[2]), "cpus": os.cpu_count(),
            "load_1min": load, "targets": TARGETS}




def live_in_session(sid: int, wait_s: float = 15.0) -> int:
    """Processes of session ``sid`` still alive after up to ``wait_s`` (zombies are dead,
    waiting for init; a SIGKILL is delivered asynchronously)."""
    import psutil

    deadline = time.monotonic() + wait_s
    while True:
        count = 0
        for p in psutil.process_iter():
            try:
                count += os.getsid(p.pid) == sid and p.status() != psutil.STATUS_ZOMBIE
            except (ProcessLookupError, PermissionError, psutil.NoSuchProcess):
                continue
        if not count or time.monotonic() > deadline:
            return count
        time.sleep(0.2)


def _sweep_command(sweep: Path, out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "orange_plan.cli", "sweep", str(sweep), "-o", str(out),
            "--workers", "2", *extra]


def run_resume_check(scenario: Path, runs: int = 200, kill_after: int = 100,
                     vertices: int = 200, step: Callable[[str], None] | None = None) -> dict:
    """Kill a sweep of ``runs`` runs after ``kill_after`` rows, rerun it (module docstring)."""
    import pandas as pd

    step = step or (lambda text: None)
    here = Path(__file__).resolve().parents[2]  # where this orange_plan is imported from
    with tempfile.TemporaryDirectory(prefix="orange-bench-resume-") as folder:
        sweep = write_seed_sweep(Path(folder), scenario, runs, vertices, "resume")
        out = Path(folder) / "resume.parquet"
        store = ResultStore(out)
        step(f"first sweep, killed after {kill_after} rows")
        t0 = time.perf_counter()
        proc = subprocess.Popen(_sweep_command(sweep, out), cwd=here, start_new_session=True,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            while proc.poll() is None and len(store.part_files()) < kill_after:
                time.sleep(0.05)
        finally:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        first_s = time.perf_counter() - t0
        if proc.returncode == 0 or not store.part_files():
            raise RuntimeError("the sweep ended before it was killed: "
                               + proc.stderr.read().decode()[-300:])
        stray = live_in_session(proc.pid)
        before = store.rows()
        step(f"rerun ({len(before)} rows stored at the kill)")
        t1 = time.perf_counter()
        done = subprocess.run(_sweep_command(sweep, out, "--json"), cwd=here,
                              capture_output=True, text=True, check=False)
        second_s = time.perf_counter() - t1
        if done.returncode != 0:
            raise RuntimeError(f"the resumed sweep failed: {done.stderr.strip()[-300:]}")
        report = json.loads(done.stdout)
        rows = pd.read_parquet(out)
    kept = rows.set_index("run_id").reindex(before["run_id"])["finished_utc"]
    return {"runs": runs, "kill_after": kill_after, "rows_at_kill": len(before),
            "stray_processes": stray, "resumed": report["resumed"], "ran_after": report["ran"],
            "final_rows": len(rows), "unique_ids": int(rows["run_id"].nunique()),
            "redone": int((kept.to_numpy() != before["finished_utc"].to_numpy()).sum()),
            "first_s": first_s, "second_s": second_s, "targets": TARGETS,
            "ok": bool(len(rows) == runs == rows["run_id"].nunique()
                       and (kept.to_numpy() == before["finished_utc"].to_numpy()).all()
                       and stray == 0)}
