"""orange-plan sweep: the sweep file, the per-run store and resume, the Dask runner on a
LocalCluster of 2 worker processes on 127.0.0.1 (a worker killed mid-sweep, a sweep process
killed and rerun), and malformed sweep files (one line, exit 2)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time

import pandas as pd
import psutil
import pytest
import tomli_w
from conftest import REPO, run_cli, write_scenario

from orange_plan.bench.sweep import live_in_session
from orange_plan.errors import InputError
from orange_plan.sweep.driver import run_sweep
from orange_plan.sweep.report import summary_rows
from orange_plan.sweep.spec import load_sweep
from orange_plan.sweep.store import ResultStore

pytestmark = pytest.mark.timeout(240)

GRID = {"battery.rated_energy_Wh": [2.0, 10.0], "robot.mass_kg": [10.0, 14.0]}


def write_sweep(folder, grid=None, seeds=2, **top) -> os.PathLike:
    """The yard scenario and a sweep of it (4 grid points x ``seeds`` by default)."""
    if not (folder / "yard.toml").exists():
        write_scenario(folder, name="yard.toml")
    data = {"name": "yard_sweep", "scenarios": ["yard.toml"], "seeds": seeds, "vertices": 120,
            **top, "grid": GRID if grid is None else grid}
    path = folder / "sweep.toml"
    path.write_text(tomli_w.dumps(data), encoding="utf-8")
    return path


@pytest.fixture
def cluster():
    """LocalCluster: 2 worker processes, 1 thread each, on 127.0.0.1; none left afterwards."""
    import dask
    from distributed import LocalCluster

    from orange_plan.cluster import ENVIRON_KEY, worker_environ

    before = {p.pid for p in psutil.Process().children(recursive=True)}
    environ = dict(os.environ)  # the nanny writes its worker variables into this process's
    with dask.config.set({ENVIRON_KEY: worker_environ()}), LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
            dashboard_address=None) as c:
        yield c
    os.environ.clear()
    os.environ.update(environ)
    assert_no_children_left(before)


def assert_no_children_left(before: set[int], wait_s: float = 10.0) -> None:
    deadline = time.monotonic() + wait_s
    while True:
        left = [p for p in psutil.Process().children(recursive=True) if p.pid not in before
                and p.is_running() and p.status() != psutil.STATUS_ZOMBIE
                and not _resource_tracker(p)]
        if not left or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    assert not left, [p.cmdline() for p in left]


def _resource_tracker(p) -> bool:
    """multiprocessing's helper: one per test process, it ends with it (not a Dask process)."""
    try:
        return "resource_tracker" in " ".join(p.cmdline())
    except psutil.NoSuchProcess:
        return True


# --- the sweep file --------------------------------------------------------------------------


def test_runs_are_scenarios_times_grid_times_seeds_with_stable_ids(tmp_path):
    sweep = load_sweep(write_sweep(tmp_path, seeds=[3, 7]))
    assert len(sweep.runs) == 2 * 2 * 2
    assert sweep.grid_keys == ("battery.rated_energy_Wh", "robot.mass_kg")
    first = sweep.runs[0]
    assert first.params == (("battery.rated_energy_Wh", 2.0), ("robot.mass_kg", 10.0))
    assert first.scenario_data["battery"]["rated_energy_Wh"] == 2.0
    assert [r.seed for r in sweep.runs[:2]] == [3, 7]
    assert len({r.run_id for r in sweep.runs}) == len(sweep.runs)
    again = load_sweep(tmp_path / "sweep.toml")
    assert [r.run_id for r in again.runs] == [r.run_id for r in sweep.runs]
    changed = load_sweep(write_sweep(tmp_path, seeds=[3, 8]))  # same runs for seed 3 only
    assert {r.run_id for r in changed.runs} & {r.run_id for r in sweep.runs} == {
        r.run_id for r in sweep.runs if r.seed == 3}


def test_a_changed_scenario_file_changes_every_id(tmp_path):
    ids = {r.run_id for r in load_sweep(write_sweep(tmp_path)).runs}
    write_scenario(tmp_path, set={"ancillary.comm_W": 1.5}, name="yard.toml")
    assert not ids & {r.run_id for r in load_sweep(tmp_path / "sweep.toml").runs}


MALFORMED = [
    ({"grid": {"battery.rated_Wh": [1.0]}}, "unknown key 'battery.rated_Wh' (did you mean "
                                            "'rated_energy_Wh'?)"),
    ({"grid": {"battery.rated_energy_Wh": [-1.0]}}, "grid point battery.rated_energy_Wh = -1.0"),
    ({"grid": {"battery.rated_energy_Wh": []}}, "must be a non-empty list"),
    ({"grid": {"mass_kg": [1.0]}}, "must be 'table.key'"),
    ({"grid": {"robot": {"mass_kg": [1.0]}}}, "must be quoted whole"),
    ({"seeds": 0}, "seeds = 0 must be >= 1"),
    ({"seeds": [1, 1]}, "seeds lists a seed twice"),
    ({"seeds": "3"}, "seeds must be a count"),
    ({"scenarios": ["nowhere.toml"]}, "scenario file 'nowhere.toml' not found"),
    ({"scenarios": []}, "scenarios must be a non-empty list"),
    ({"vertices": 10}, "vertices = 10 must be an integer >= 50"),
    ({"sample_rate_Hz": 0}, "sample_rate_Hz = 0 must be a number > 0"),
    ({"truth": "calibraton"}, "did you mean 'calibration'"),
    ({"truth": "missing.toml"}, "missing.toml"),
    ({"seed": 3}, "unknown key 'seed' (did you mean 'seeds'?)"),
]


@pytest.mark.parametrize(("change", "message"), MALFORMED)
def test_malformed_sweep_is_one_line_and_exit_2(tmp_path, change, message):
    path = write_sweep(tmp_path)
    data = {"name": "bad", "scenarios": ["yard.toml"], "seeds": 1, "grid": GRID} | change
    path.write_text(tomli_w.dumps(data), encoding="utf-8")
    code, stdout, stderr = run_cli("sweep", path, "-o", tmp_path / "r.parquet")
    assert code == 2, stderr
    assert stderr.count("\n") == 1 and stderr.startswith("orange-plan: error: ")
    assert message in stderr and str(path) in stderr
    assert stdout == "" and not (tmp_path / "r.parquet").exists()


def test_bad_toml_and_bad_outputs_are_exit_2(tmp_path):
    path = write_sweep(tmp_path)
    bad = tmp_path / "bad.toml"
    bad.write_text("scenarios = [\n", encoding="utf-8")
    for args, message in (([bad, "-o", tmp_path / "r.parquet"], "not a valid TOML file"),
                          ([path, "-o", tmp_path / "r.csv"], "must end in .parquet"),
                          ([path, "-o", tmp_path / "r.parquet", "--png", tmp_path / "f.jpg"],
                           "must end in .png"),
                          ([path, "-o", tmp_path / "r.parquet", "--scheduler", "localhost"],
                           "must look like tcp://HOST:PORT"),
                          ([path, "-o", tmp_path / "r.parquet", "--workers", "0"],
                           "--workers = 0 must be >= 1")):
        code, _, stderr = run_cli("sweep", *args)
        assert code == 2 and message in stderr and stderr.count("\n") == 1, stderr


# --- the store ---------------------------------------------------------------------------------


def row(run_id: str, index: int, value: float = 1.0) -> dict:
    return {"run_id": run_id, "index": index, "coverage_m2": value, "error": None}


def test_store_keeps_the_first_row_of_an_id_and_removes_parts(tmp_path):
    store = ResultStore(tmp_path / "r.parquet")
    store.add(row("b", 1))
    store.add(row("a", 0))
    store.consolidate()
    assert not store.parts.exists()
    store.add(row("a", 0, 99.0))  # a rerun of a task a killed worker had finished
    store.add(row("c", 2))
    (store.parts / ".d.parquet.x1y2.parquet").write_bytes(b"")  # a write the kill cut short
    assert store.done_ids() == {"a", "b", "c"}
    rows = store.consolidate()
    assert list(rows["run_id"]) == ["a", "b", "c"]
    assert list(rows["coverage_m2"]) == [1.0, 1.0, 1.0]
    assert list(pd.read_parquet(store.path)["run_id"]) == ["a", "b", "c"]


def test_store_of_another_sweep_is_refused(tmp_path):
    store = ResultStore(tmp_path / "r.parquet")
    store.add(row("x", 0))
    with pytest.raises(InputError, match="1 run\\(s\\) that are not in this sweep"):
        store.check_belongs(["a", "b"])
    store.check_belongs(["x", "a"])


def test_summary_counts_per_grid_point():
    rows = pd.DataFrame([
        {"scenario": "s", "k": 1, "stranded": True, "planned": True, "error": None,
         "coverage_m2": 10.0, "energy_left_J": -5.0, "run_s": 1.0},
        {"scenario": "s", "k": 1, "stranded": False, "planned": True, "error": None,
         "coverage_m2": 30.0, "energy_left_J": 2000.0, "run_s": 3.0},
        {"scenario": "s", "k": 2, "stranded": None, "planned": None, "error": "PlanningError",
         "coverage_m2": None, "energy_left_J": None, "run_s": 0.5},
        {"scenario": "s", "k": 2, "stranded": False, "planned": False, "error": None,
         "coverage_m2": 0.0, "energy_left_J": 4000.0, "run_s": 0.1}])
    one, two = summary_rows(rows, ["k"])
    assert (one["runs"], one["errors"], one["strandings"], one["stayed_home"]) == (2, 0, 1, 0)
    assert one["coverage_m2"] == 20.0 and one["energy_left_at_home_kJ"] == 2.0
    assert (two["runs"], two["errors"], two["strandings"], two["stayed_home"]) == (2, 1, 0, 1)
    assert two["run_s"] == pytest.approx(0.3)


# --- on Dask -----------------------------------------------------------------------------------


def test_sweep_on_an_existing_cluster_then_resumed_redoes_nothing(tmp_path, cluster):
    path = write_sweep(tmp_path)
    out, png = tmp_path / "r.parquet", tmp_path / "r.png"
    code, stdout, stderr = run_cli("sweep", path, "-o", out, "--png", png, "--json",
                                   "--scheduler", cluster.scheduler_address)
    assert code == 0, stderr
    report = json.loads(stdout)
    assert (report["runs"], report["ran"], report["resumed"]) == (8, 8, 0)
    rows = pd.read_parquet(out)
    sweep = load_sweep(path)
    assert list(rows["run_id"]) == [r.run_id for r in sweep.runs]
    assert rows["error"].isna().all() and rows["planned"].all()
    assert (rows["coverage_m2"] > 0).all() and rows["version"].eq("0.1.0").all()
    assert rows["worker"].nunique() == 2  # both workers ran
    assert set(rows["battery.rated_energy_Wh"]) == {2.0, 10.0}
    # energy left = usable energy - energy drawn, and it is what strands a run
    assert ((rows["energy_left_J"] < 0) <= rows["stranded"]).all()
    assert len(report["summary"]) == 4 and png.stat().st_size > 10_000
    code, stdout, stderr = run_cli("sweep", path, "-o", out, "--json",
                                   "--scheduler", cluster.scheduler_address)
    assert code == 0, stderr
    again = json.loads(stdout)
    assert (again["runs"], again["ran"], again["resumed"]) == (8, 0, 8)
    pd.testing.assert_frame_equal(pd.read_parquet(out), rows)


def test_a_worker_killed_mid_sweep_loses_and_duplicates_no_row(tmp_path, cluster):
    from distributed import Client

    sweep = load_sweep(write_sweep(tmp_path, seeds=4))
    store = ResultStore(tmp_path / "r.parquet")
    done = threading.Event()
    outcome = {}

    def sweep_in_background():
        outcome["result"] = run_sweep(sweep, store, scheduler=cluster.scheduler_address)
        done.set()

    thread = threading.Thread(target=sweep_in_background)
    thread.start()
    with Client(cluster.scheduler_address) as client:
        victim, in_flight = None, []
        while victim is None and not done.is_set():  # a worker with a run in progress
            busy = {w: keys for w, keys in client.processing().items() if keys}
            if busy and len(store.part_files()) >= 2:
                victim, in_flight = next(iter(busy.items()))
            time.sleep(0.05)
        assert victim is not None, "the sweep ended before a worker could be killed"
        pid = client.run(os.getpid, workers=[victim])[victim]
        os.kill(pid, signal.SIGKILL)
        thread.join(120)
    assert done.is_set()
    rows = outcome["result"].rows
    assert sorted(rows["run_id"]) == sorted(r.run_id for r in sweep.runs)
    assert rows["run_id"].is_unique and len(pd.read_parquet(store.path)) == len(sweep.runs)
    in_flight = [str(k).removeprefix("orange-plan-") for k in in_flight]
    assert in_flight and rows["run_id"].isin(in_flight).sum() == len(in_flight)


def test_killed_sweep_process_resumes_without_redoing_finished_runs(tmp_path):
    path = write_sweep(tmp_path, seeds=3)
    out = tmp_path / "r.parquet"
    store = ResultStore(out)
    n = len(load_sweep(path).runs)
    proc = subprocess.Popen([sys.executable, "-m", "orange_plan.cli", "sweep", str(path),
                             "-o", str(out), "--workers", "2"], cwd=REPO,
                            start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while len(store.part_files()) < 3 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert proc.poll() is None, "the sweep finished before it could be killed"
    finally:  # the whole session: the sweep, its scheduler and its worker processes
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert live_in_session(proc.pid) == 0
    finished = store.rows()
    assert 3 <= len(finished) < n and not out.exists()
    code, stdout, stderr = run_cli("sweep", path, "-o", out, "--json")
    assert code == 0, stderr
    report = json.loads(stdout)
    assert (report["runs"], report["resumed"], report["ran"]) == (n, len(finished),
                                                                  n - len(finished))
    rows = pd.read_parquet(out)
    assert len(rows) == n and rows["run_id"].is_unique
    kept = rows.set_index("run_id").loc[finished["run_id"], "finished_utc"]
    assert list(kept) == list(finished["finished_utc"])  # not redone


def test_an_unreachable_scheduler_is_exit_2(tmp_path):
    code, _, stderr = run_cli("sweep", write_sweep(tmp_path), "-o", tmp_path / "r.parquet",
                              "--scheduler", "tcp://127.0.0.1:9")
    assert code == 2 and "--scheduler tcp://127.0.0.1:9: no Dask scheduler answers" in stderr
    assert stderr.count("\n") == 1


def test_bench_sweep_small_run_meets_its_own_bookkeeping(tmp_path):
    """Structure only (the measured figures are docs/benchmarks/sweep.md's): both timings per repeat, and
    the kill-and-resume check ending with one row per run, none redone, no process left."""
    write_scenario(tmp_path, name="yard.toml")
    code, stdout, stderr = run_cli("bench", "sweep", tmp_path / "yard.toml", "--runs", "2",
                                   "--repeats", "1", "--vertices", "60", "--resume-runs", "6",
                                   "--json")
    assert code == 0, stderr
    result = json.loads(stdout)
    from test_json_docs import compare

    compare("bench sweep", result)  # docs/json.md lists exactly these keys
    speed = result["speedup"]
    assert len(speed["seconds_1_worker"]) == len(speed["seconds_2_workers"]) == 1
    assert speed["speedup"] == pytest.approx(speed["median_1_worker_s"]
                                             / speed["median_2_workers_s"])
    resume = result["resume"]
    assert resume["ok"] and resume["final_rows"] == resume["unique_ids"] == 6
    assert resume["resumed"] == resume["rows_at_kill"] >= 3
    assert resume["resumed"] + resume["ran_after"] == 6
    assert resume["redone"] == 0 and resume["stray_processes"] == 0


def test_local_workers_keep_glibcs_own_trim_threshold():
    """Dask's MALLOC_TRIM_THRESHOLD_ = 64 KiB made every run twice as slow (orange_plan/cluster.py)."""
    from orange_plan.cluster import dask_client

    before = dict(os.environ)
    with dask_client(1) as client:
        environ = client.run(lambda: dict(os.environ))
    (env,) = environ.values()
    assert env.get("OMP_NUM_THREADS") == "1"
    assert "MALLOC_TRIM_THRESHOLD_" not in env or env["MALLOC_TRIM_THRESHOLD_"] == before.get(
        "MALLOC_TRIM_THRESHOLD_")  # only a threshold the user set is passed on
    assert dict(os.environ) == before  # the nanny's writes into this process are undone
