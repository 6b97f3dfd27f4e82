"""Every shipped example: scenarios/*.toml run through ``orange-plan range``; maps/*.geojson load."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, run_cli

from orange_plan.scenario import load_scenario
from orange_plan.world.geomap import load_map

SCENARIOS = sorted((REPO / "scenarios").glob("*.toml"))
MAPS = sorted((REPO / "maps").glob("*.geojson"))

# One example per robot system (the paper's robots and its future work).
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


INDOOR_MAPS = {"home_floor", "lab_box", "lab_ramp"}
"""Maps of rooms: no place on the Earth to export to; every other map has an ``origin``."""


def example_for_map(map_stem: str):
    """The first shipped scenario whose map is ``maps/<map_stem>.geojson``."""
    for path in SCENARIOS:
        if Path(load_scenario(path).map_path).stem == map_stem:
            return path
    pytest.fail(f"no shipped scenario uses maps/{map_stem}.geojson")


def short_tour(world, step_m: float = 3.0) -> np.ndarray:
    """Home -> a free point ``step_m`` away -> home: the smallest tour to export."""
    home = np.asarray(world.home_xy_m, float)
    for angle in np.radians(np.arange(0, 360, 15)):
        there = home + step_m * np.array([np.cos(angle), np.sin(angle)])
        tour = np.array([home, there, home])
        if world.is_free(*there) and world.segments_free(tour[:-1], tour[1:]).all():
            return tour
    pytest.fail("no free point 3 m from home")


OUTDOOR = [p for p in MAPS if p.stem not in INDOOR_MAPS]


@pytest.mark.parametrize("map_path", OUTDOOR, ids=[p.stem for p in OUTDOOR])
@pytest.mark.parametrize("fmt, name", [("qgc", "m.plan"), ("mavlink", "m.waypoints")])
def test_every_outdoor_example_exports(map_path, fmt, name, tmp_path):
    from orange_plan.context import load_context
    from orange_plan.export.autopilot import latlon_to_xy, read_items

    scenario = example_for_map(map_path.stem)
    ctx = load_context(scenario)
    origin = ctx.world.map.origin
    assert origin is not None, f"{map_path.name} has no origin"
    tour = short_tour(ctx.world)
    plan = tmp_path / "plan.geojson"
    plan.write_text(json.dumps({"type": "FeatureCollection", "features": [{
        "type": "Feature", "properties": {"kind": "tour"},
        "geometry": {"type": "LineString", "coordinates": tour.tolist()}}]}), encoding="utf-8")
    altitude = ["--altitude-m", "20"] if ctx.scenario.robot.kind == "aerial" else []
    code, _, err = run_cli("export", plan, "--scenario", scenario, "--format", fmt,
                           "-o", tmp_path / name, *altitude)
    assert code == 0, err
    home, items = read_items(tmp_path / name)
    hx, hy = latlon_to_xy(origin, home[0], home[1])
    assert math.hypot(hx - tour[0, 0], hy - tour[0, 1]) < 0.1
    assert len(items) >= 3
