"""Properties of a sweep: its runs are exactly scenarios x grid x seeds (against a plain
nested enumeration), and a store filled by any interrupted-then-resumed sequence of runs, with
reruns of runs a killed worker had started, ends with exactly one row per run (against a dict
of the first result of each id)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import tomli_w
from conftest import write_scenario
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from orange_plan.sweep.spec import load_sweep
from orange_plan.sweep.store import ResultStore

KEYS = ("battery.rated_energy_Wh", "robot.mass_kg", "ancillary.comm_W",
        "mission.sensor_radius_m")
"""Scenario keys of the yard that take any positive number."""

grids = st.dictionaries(
    st.sampled_from(KEYS),
    st.lists(st.floats(0.5, 50.0).map(lambda v: round(v, 3)), min_size=1, max_size=3,
             unique=True), max_size=3)
seed_lists = st.lists(st.integers(0, 10_000), min_size=1, max_size=3, unique=True)


def reference_runs(scenarios, grid: dict, seeds) -> list[tuple]:
    """(scenario, {key: value}, seed) in the documented order, by recursion over the keys."""
    def points(keys):
        if not keys:
            return [{}]
        return [{keys[0]: v, **rest} for v in grid[keys[0]] for rest in points(keys[1:])]

    return [(s, p, seed) for s in scenarios for p in points(list(grid)) for seed in seeds]


@settings(max_examples=40, deadline=None, suppress_health_check=[
    HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(grid=grids, seeds=seed_lists, two=st.booleans())
def test_runs_are_the_product_in_order(tmp_path_factory, grid, seeds, two):
    folder = tmp_path_factory.mktemp("sweep")
    scenarios = ["a.toml", "b.toml"] if two else ["a.toml"]
    for i, name in enumerate(scenarios):
        write_scenario(folder, set={"name": f"s{i}"}, name=name)
    path = folder / "sweep.toml"
    path.write_text(tomli_w.dumps({"scenarios": scenarios, "seeds": seeds, "grid": grid}),
                    encoding="utf-8")
    runs = load_sweep(path).runs
    expected = reference_runs(scenarios, grid, seeds)
    assert len(runs) == len(expected)
    for run, (scenario, point, seed) in zip(runs, expected):
        assert (run.scenario_file, dict(run.params), run.seed) == (scenario, point, seed)
        for dotted, value in point.items():
            table, key = dotted.split(".")
            assert run.scenario_data[table][key] == value
    assert [r.index for r in runs] == list(range(len(runs)))
    assert len({r.run_id for r in runs}) == len(runs)


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 12), data=st.data())
def test_interrupted_and_resumed_store_has_one_row_per_run(n, data):
    ids = [f"run{i:02d}" for i in range(n)]
    first_pass = data.draw(st.permutations(ids).flatmap(
        lambda order: st.integers(0, n).map(lambda k: order[:k])), label="finished before kill")
    reruns = data.draw(st.lists(st.sampled_from(ids), max_size=4), label="reruns")
    with tempfile.TemporaryDirectory() as folder:
        store = ResultStore(Path(folder) / "r.parquet")
        reference: dict[str, int] = {}

        def finish(run_id: str, attempt: int) -> None:
            store.add({"run_id": run_id, "index": ids.index(run_id), "attempt": attempt})
            reference.setdefault(run_id, attempt)

        for run_id in first_pass:
            finish(run_id, 1)
        if data.draw(st.booleans(), label="consolidated before the kill"):
            store.consolidate()
        pending = [i for i in ids if i not in store.done_ids()]
        assert sorted(pending) == sorted(set(ids) - set(first_pass))
        for run_id in [*pending, *reruns]:  # reruns: a killed worker's task finished twice
            finish(run_id, 2)
        rows = store.consolidate()
    assert list(rows["run_id"]) == ids
    assert dict(zip(rows["run_id"], rows["attempt"])) == reference
