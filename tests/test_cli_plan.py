"""``orange-plan plan``: the plan file (docs/formats.md), the JSON summary, refusals, and simulate flying it."""

from __future__ import annotations

import json
import math
import os
import stat

import numpy as np
import pandas as pd
import pytest
from conftest import run_cli
from planning_worlds import box, write_world

SUMMARY = ("energy_available_J", "energy_planned_J", "reserve_J", "coverage_m2",
           "coverage_fraction", "coverage_bound_m2", "duration_s", "return_probability",
           "planner_seconds")
ARRAYS = ("t_s", "speed_mps", "energy_used_J", "energy_to_home_J", "margin_J")


def check_plan_file(data: dict, home) -> None:
    """Validate a plan against its format (docs/formats.md: every rule stated there, nothing
    more)."""
    assert data["type"] == "FeatureCollection"
    kinds = [f["properties"]["kind"] for f in data["features"]]
    assert kinds.count("tour") == 1 and kinds.count("covered") == 1
    assert set(kinds) <= {"tour", "waypoint", "covered"}
    tour = next(f for f in data["features"] if f["properties"]["kind"] == "tour")
    assert tour["geometry"]["type"] == "LineString"
    coords = np.asarray(tour["geometry"]["coordinates"], float)
    assert coords.shape[1] == 2 and len(coords) >= 2
    assert np.allclose(coords[0], home) and np.allclose(coords[-1], home)
    for key in ARRAYS:
        values = tour["properties"][key]
        assert len(values) == len(coords), key
        assert all(isinstance(v, (int, float)) and math.isfinite(v) for v in values), key
    props = tour["properties"]
    assert min(props["margin_J"]) >= 0
    assert np.all(np.diff(props["energy_used_J"]) >= 0)
    assert np.all(np.diff(props["t_s"]) >= 0) and props["t_s"][-1] > props["t_s"][0]
    assert min(props["speed_mps"]) > 0
    assert props["energy_to_home_J"][-1] == 0
    waypoints = [f for f in data["features"] if f["properties"]["kind"] == "waypoint"]
    assert all(f["geometry"]["type"] == "Point" for f in waypoints)
    assert sorted(f["properties"]["order"] for f in waypoints) == list(range(len(waypoints)))
    covered = next(f for f in data["features"] if f["properties"]["kind"] == "covered")
    assert covered["geometry"]["type"] in ("Polygon", "MultiPolygon")
    summary = data["summary"]
    for key in SUMMARY:
        assert isinstance(summary[key], (int, float)) and math.isfinite(summary[key]), key
    assert 0 <= summary["coverage_fraction"] <= 1
    assert 0 <= summary["return_probability"] <= 1
    assert summary["coverage_m2"] <= summary["coverage_bound_m2"] * 1.001
    assert summary["energy_planned_J"] + summary["reserve_J"] <= summary["energy_available_J"]
    assert summary["energy_planned_J"] == pytest.approx(props["energy_used_J"][-1]
                                                        - props["energy_used_J"][0])


@pytest.fixture
def world(tmp_path):
    return write_world(tmp_path, width_m=30.0, height_m=20.0, obstacles=[(12, 4, 16, 12)],
                       hill=(20.0, 10.0, 3.0, 5.0), rated_energy_Wh=1.0)


def test_plan_writes_spec_file_and_json(world, tmp_path):
    out = tmp_path / "plan.geojson"
    png = tmp_path / "plan.png"
    old = os.umask(0o022)
    try:
        code, stdout, stderr = run_cli("plan", world, "-o", out, "--png", png,
                                       "--vertices", "300", "--json")
    finally:
        os.umask(old)
    assert code == 0, stderr
    report = json.loads(stdout)
    data = json.loads(out.read_text())
    check_plan_file(data, (2.0, 2.0))
    for key in SUMMARY:
        assert report[key] == pytest.approx(data["summary"][key])
    # Outputs get the user's umask like any other program's (not the temp file's 0600).
    assert stat.S_IMODE(out.stat().st_mode) == 0o644
    assert stat.S_IMODE(png.stat().st_mode) == 0o644
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_simulate_flies_the_plan_file_unchanged(world, tmp_path):
    out = tmp_path / "plan.geojson"
    assert run_cli("plan", world, "-o", out, "--vertices", "300")[0] == 0
    rec = tmp_path / "rec.csv"
    code, _, stderr = run_cli("simulate", world, out, "-o", rec, "--seed", "1")
    assert code == 0, stderr
    frame = pd.read_csv(rec)
    tour = next(f for f in json.loads(out.read_text())["features"]
                if f["properties"]["kind"] == "tour")
    coords = np.asarray(tour["geometry"]["coordinates"])
    driven = frame[["x_m", "y_m"]].to_numpy()
    # Every recorded position lies on the planned polyline (within position noise) and the
    # run ends at home: the simulator drove the plan as written.
    from shapely.geometry import LineString, Point

    line = LineString(coords)
    dist = np.array([line.distance(Point(p)) for p in driven[:: max(1, len(driven) // 300)]])
    assert np.percentile(dist, 95) < 0.5
    assert np.hypot(*(driven[-1] - coords[-1])) < 1.0


@pytest.mark.parametrize("case, message", [
    ("boxed", "boxed in"),
    ("small", "too small"),
])
def test_infeasible_requests_are_one_line_exit_2(tmp_path, case, message):
    if case == "boxed":  # home walled into a 1 m x 1 m pocket (footprint radius 1 m)
        walls = [(0.0, 1.0, 2.0, 1.5), (1.0, 0.0, 1.5, 1.0)]
        scenario = write_world(tmp_path, width_m=30.0, height_m=20.0, obstacles=walls,
                               home=(0.5, 0.5))
    else:
        scenario = write_world(tmp_path, width_m=30.0, height_m=20.0, rated_energy_Wh=0.004)
    out = tmp_path / "plan.geojson"
    code, _stdout, stderr = run_cli("plan", scenario, "-o", out, "--vertices", "200")
    assert code == 2
    assert message in stderr and len(stderr.strip().splitlines()) == 1
    assert not out.exists()


def test_sensor_radius_zero_is_refused(tmp_path):
    scenario = write_world(tmp_path)
    text = scenario.read_text().replace("sensor_radius_m = 1.0", "sensor_radius_m = 0.0")
    scenario.write_text(text)
    code, _, stderr = run_cli("plan", scenario, "-o", tmp_path / "p.geojson")
    assert code == 2 and "sensor_radius_m" in stderr


def test_bad_output_names_are_refused_before_work(world, tmp_path):
    assert run_cli("plan", world, "-o", tmp_path / "plan.txt")[0] == 2
    assert run_cli("plan", world, "-o", tmp_path / "p.geojson", "--png", tmp_path / "x.jpg")[0] == 2
    assert run_cli("plan", world, "-o", tmp_path)[0] == 2
    assert run_cli("plan", world, "-o", tmp_path / "p.geojson", "--cost", "magic")[0] == 2


def test_box_helper_is_closed():
    ring = box(0, 0, 1, 1)[0]
    assert ring[0] == ring[-1]


@pytest.mark.parametrize("reserve, warned", [({"fraction": 0.0}, True),
                                             ({"confidence": 0.95}, False)])
def test_a_plan_unlikely_to_get_home_is_said_so(tmp_path, reserve, warned):
    """Below the documented probability of getting home, one warning line on stderr and the
    same text in the JSON's ``warnings``; a confidence reserve keeps it above that."""
    from orange_plan.planning.reach import RETURN_PROBABILITY_WARN

    scenario = write_world(tmp_path, width_m=30.0, height_m=20.0, rated_energy_Wh=1.0,
                           reserve=reserve)
    code, stdout, stderr = run_cli("plan", scenario, "-o", tmp_path / "plan.geojson",
                                   "--vertices", "300", "--json")
    assert code == 0, stderr
    report = json.loads(stdout)
    assert (report["return_probability"] < RETURN_PROBABILITY_WARN) is warned
    lines = [line for line in stderr.splitlines() if "warning" in line]
    if warned:
        assert len(lines) == 1 and len(report["warnings"]) == 1
        assert report["warnings"][0] in lines[0]
        assert f"{report['return_probability']:.2f}" in lines[0] and "fraction = 0" in lines[0]
    else:
        assert lines == [] and report["warnings"] == []
