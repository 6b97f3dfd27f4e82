"""``bench replan``: a quick run on a small world completes, and every replan is safe."""

from __future__ import annotations

import json

from conftest import run_cli
from planning_worlds import write_world


def test_bench_replan_quick(tmp_path):
    scenario = write_world(tmp_path, width_m=40.0, height_m=30.0, rated_energy_Wh=1.0)
    code, stdout, stderr = run_cli("bench", "replan", scenario, "--replans", "3",
                                   "--vertices", "200", "--json")
    assert code == 0, stderr
    result = json.loads(stdout)
    assert result["replans"] == 3 and result["all_safe"] is True
    assert 0 < result["median_s"] <= result["p95_s"] <= result["max_s"]
    assert 0 < result["cpu_median_s"] <= result["cpu_p95_s"]
    assert len(result["load_before"]) == 3 == len(result["load_after"])
    assert result["target_p95_s"] == 0.25


def test_bench_replan_refuses_zero_replans(tmp_path):
    scenario = write_world(tmp_path)
    code, _, stderr = run_cli("bench", "replan", scenario, "--replans", "0")
    assert code == 2 and "--replans" in stderr
