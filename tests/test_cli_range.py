"""``orange-plan range``: output contract and the bad-file contract (one line, exit 2)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from conftest import BOUNDARY, base_features, feature, run_cli, write_asc, write_scenario


def bow_tie_features():
    return [feature("boundary", "Polygon", [[[0, 0], [20, 10], [20, 0], [0, 10], [0, 0]]]),
            feature("home", "Point", [2.0, 5.0])]


def write_non_toml(folder):
    write_scenario(folder)
    path = folder / "scenario.toml"
    path.write_text('name = "x"\n[robot\nmass_kg = 3\n', encoding="utf-8")
    return path


def write_not_covering_raster(folder):
    write_asc(folder / "dem.asc", [[0.0] * 5] * 5, 1.0, 0.0, 0.0)  # 5 m x 5 m of a 20 x 10 yard
    return write_scenario(folder, elevation="dem.asc")


# (id, how to write the bad file into tmp_path, text the error line must contain)
BAD_FILES = [
    ("missing_key", lambda d: write_scenario(d, drop=["robot.mass_kg"]),
     "missing key 'robot.mass_kg'"),
    ("unknown_key_hint", lambda d: write_scenario(d, set={"battery.rated_energy_wh": 5.0}),
     "unknown key 'battery.rated_energy_wh' (did you mean 'rated_energy_Wh'?)"),
    ("negative_mass", lambda d: write_scenario(d, set={"robot.mass_kg": -5.0}),
     "robot.mass_kg = -5 must be > 0"),
    ("loss_of_one", lambda d: write_scenario(d, set={"losses.motor": 1.0}),
     "losses.motor = 1 must be a loss fraction in [0, 1) (efficiency in (0, 1])"),
    ("negative_loss", lambda d: write_scenario(d, set={"losses.battery": -0.1}),
     "losses.battery = -0.1 must be a loss fraction"),
    ("duty_cycle_zero", lambda d: write_scenario(d, set={"mission.duty_cycle": 0.0}),
     "mission.duty_cycle = 0 must be in (0, 1]"),
    ("bow_tie_boundary", lambda d: write_scenario(d, map_features=bow_tie_features()),
     "feature 0 (boundary) is self-intersecting"),
    ("home_in_obstacle", lambda d: write_scenario(
        d, map_features=[*base_features()[:3], feature("home", "Point", [5.0, 8.0])]),
     "feature 3 (home) lies inside an obstacle or no-go zone"),
    ("surface_crr_1_5", lambda d: write_scenario(d, map_features=[
        feature("boundary", "Polygon", [BOUNDARY]), feature("home", "Point", [2.0, 5.0]),
        feature("surface", "Polygon", [[[10, 0], [20, 0], [20, 10], [10, 0]]], name="ice", crr=1.5)]),
     "feature 2 (surface 'ice') has crr = 1.5 outside [0, 1]"),
    ("robot_crr_negative", lambda d: write_scenario(d, set={"robot.crr": -0.1}),
     "robot.crr = -0.1 must be in [0, 1]"),
    ("missing_raster", lambda d: write_scenario(d, elevation="gone_dem.asc"),
     "elevation raster 'gone_dem.asc' not found"),
    ("raster_not_covering", write_not_covering_raster,
     "elevation raster 'dem.asc' covers x 0..5, y 0..5 m but the boundary spans x 0..20"),
    ("empty_map", lambda d: write_scenario(d, map_features=[]), "empty map (no features"),
    ("non_toml", write_non_toml, "not a valid TOML file"),
    ("mass_wrong_type", lambda d: write_scenario(d, set={"robot.mass_kg": "abc"}),
     "robot.mass_kg must be a number, got 'abc'"),
    ("v_min_above_v_max", lambda d: write_scenario(d, set={"robot.v_min_mps": 1.5}),
     "robot.v_min_mps = 1.5 exceeds robot.v_max_mps = 1.0"),
    ("missing_map_file", lambda d: write_scenario(d, set={"map": "elsewhere.geojson"}),
     "map file 'elsewhere.geojson' not found"),
    ("unknown_map_kind", lambda d: write_scenario(
        d, map_features=[*base_features(), feature("hom", "Point", [3.0, 3.0])]),
     "feature 4 has unknown kind 'hom'"),
    ("missing_scenario_file", lambda d: d / "no_such_scenario.toml", "scenario file not found"),
    ("scenario_home_in_obstacle", lambda d: write_scenario(d, set={"mission.home_xy_m": [5.0, 8.0]}),
     "home at (5, 8) m is inside an obstacle or no-go zone"),
    ("misspelt_map_member", lambda d: write_scenario(d, elevaton="dem.asc"),
     "unknown top-level member 'elevaton' (did you mean 'elevation'?)"),
    ("unknown_robot_kind", lambda d: write_scenario(d, set={"robot.kind": "arial"}),
     "did you mean 'aerial'?"),
]


def assert_one_line_error(code, stdout, stderr, expected):
    assert code == 2, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith("orange-plan: error: ")
    assert expected in lines[0]
    assert "Traceback" not in stderr
    assert stdout == ""


@pytest.mark.parametrize(("writer", "expected"), [b[1:] for b in BAD_FILES],
                         ids=[b[0] for b in BAD_FILES])
def test_bad_file_gives_one_line_and_exit_2(tmp_path, writer, expected):
    path = writer(tmp_path)
    assert_one_line_error(*run_cli("range", path, "--json"), expected)


@pytest.mark.parametrize("case", ["unknown_key_hint", "bow_tie_boundary", "non_toml"])
def test_bad_file_real_process_exit_code(tmp_path, case):
    _, writer, expected = next(b for b in BAD_FILES if b[0] == case)
    path = writer(tmp_path)
    proc = subprocess.run([sys.executable, "-m", "orange_plan.cli", "range", str(path)],
                          capture_output=True, text=True, check=False)
    assert_one_line_error(proc.returncode, proc.stdout, proc.stderr, expected)


def test_range_json_is_one_object(scenario_path):
    code, out, err = run_cli("range", scenario_path, "--json")
    assert code == 0 and err == ""
    data = json.loads(out)
    assert set(data) >= {"d_max_m", "v_opt_mps", "energy", "generalised"}
    assert set(data["energy"]) >= {"available_J", "ancillary_J", "traversal_J",
                                   "battery_loss_eta1_J", "motor_loss_eta2_J",
                                   "mechanical_loss_eta3_J", "ancillary_loss_eta4_J"}


def test_range_table_for_people(scenario_path):
    code, out, _ = run_cli("range", scenario_path)
    assert code == 0
    for text in ("d_max", "v_opt", "available", "motor loss eta_2", "1,494.5 m"):
        assert text in out


def test_range_help():
    code, out, _ = run_cli("range", "--help")
    assert code == 0 and "scenario" in out.lower() and "--json" in out


def test_range_honours_the_time_limit_in_json_and_text(tmp_path):
    path = write_scenario(tmp_path, set={"mission.time_limit_s": 60.0})
    code, out, err = run_cli("range", path, "--json")
    assert code == 0, err
    data = json.loads(out)
    assert data["time_limit_s"] == 60.0 and data["within_time_limit"] is False
    assert "exceeds mission.time_limit_s = 60 s" in data["reason"]
    assert data["time_limited"]["mission_time_s"] <= 60.0 * (1 + 1e-9)
    assert data["generalised"]["time_limited"]["mission_time_s"] <= 60.0 * (1 + 1e-9)
    code, out, _ = run_cli("range", path)
    assert code == 0 and "exceeds mission.time_limit_s = 60 s" in out
    assert "d_max within time limit" in out
