"""Every shipped example: scenarios/*.toml run through ``orange-plan range``; maps/*.geojson load."""

from __future__ import annotations

import json
import math

import pytest
from conftest import REPO, run_cli

from orange_plan.scenario import load_scenario
from orange_plan.world.geomap import load_map

SCENARIOS = sorted((REPO / "scenarios").glob("*.toml"))
MAPS = sorted((REPO / "maps").glob("*.geojson"))

# One example per robot system of issue #2 (the paper's robots and its future work).
EXPECTED = ["rusti_v1_box", "rusti_v1_ramp", "ar_drone_wind", "kiwibot_campus", "vacuum_home",
            "marine_survey"] + [f"rusti_v2_{s}_{b}_{v}" for s in ("grass", "asphalt", "tile")
                                for b in ("1500mAh", "2200mAh") for v in ("v0544", "v0952")]


def test_every_robot_system_has_an_example():
    names = {p.stem for p in SCENARIOS}
    assert not set(EXPECTED) - names, f"missing examples: {sorted(set(EXPECTED) - names)}"
    assert MAPS


@pytest.mark.parametrize("path", SCENARIOS, ids=[p.stem for p in SCENARIOS])
def test_range_runs_on_example(path):
    code, out, err = run_cli("range", path, "--json")
    assert code == 0, err
    data = json.loads(out)
    robot = load_scenario(path).robot
    assert math.isfinite(data["d_max_m"]) and data["d_max_m"] > 0
    assert robot.v_min_mps - 1e-9 <= data["v_opt_mps"] <= robot.v_max_mps + 1e-9
    g = data["generalised"]
    assert math.isfinite(g["d_max_m"]) and g["d_max_m"] > 0
    assert robot.v_min_mps - 1e-9 <= g["v_opt_mps"] <= robot.v_max_mps + 1e-9
    assert data["energy"]["available_J"] > 0


@pytest.mark.parametrize("path", MAPS, ids=[p.stem for p in MAPS])
def test_example_map_loads(path):
    m = load_map(path)
    assert m.boundary.area > 0
    assert m.free_space.area > 0
