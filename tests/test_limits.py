"""Limits. Absurd or out-of-contract input is one line with exit 2, no raw
library warning reaches stderr, and ``--json`` stdout stays one JSON object."""

from __future__ import annotations

import copy
import json
import struct

import numpy as np
import pytest
from conftest import BOUNDARY, base_features, feature, run_cli, write_map, write_scenario
from logbuilders import write_ulog

from orange_plan.errors import MapError
from orange_plan.world.geomap import load_map

ROUTE = "x_m,y_m,speed_mps\n1,1,100\n18,1,100\n18,4,0.01\n"


def one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("orange-plan: error: ")
    return lines[0]


# --- maps ---------------------------------------------------------------------------------
def test_huge_coordinates_are_refused(tmp_path):
    big = [[x * 1e300, y * 1e300] for x, y in BOUNDARY]
    path = write_map(tmp_path, [feature("boundary", "Polygon", [big])])
    with pytest.raises(MapError, match=r"feature 0 \(boundary\) has a coordinate .* beyond 1e\+07 m"):
        load_map(path)


def test_deeply_nested_json_is_one_line(tmp_path):
    path = tmp_path / "deep.geojson"
    path.write_text("[" * 100_000 + "]" * 100_000, encoding="utf-8")
    with pytest.raises(MapError, match="nested too deeply"):
        load_map(path)
    scenario = write_scenario(tmp_path)
    code, _, err = run_cli("simulate", scenario, path, "-o", tmp_path / "r.csv")
    assert code == 2 and "nested too deeply" in one_line(err)


def test_deeply_nested_toml_is_one_line(tmp_path):
    path = tmp_path / "deep.toml"
    path.write_text("a = " + "[" * 100_000 + "]" * 100_000 + "\n", encoding="utf-8")
    code, _, err = run_cli("range", path)
    assert code == 2 and "nested too deeply" in one_line(err)


def test_unclosed_ring_is_refused_not_repaired(tmp_path):
    features = copy.deepcopy(base_features())
    features[2]["geometry"]["coordinates"][0].pop()  # the obstacle's closing position
    path = write_map(tmp_path, features)
    with pytest.raises(MapError, match=r"feature 2 \(obstacle\): ring 0 is not closed"):
        load_map(path)


@pytest.mark.parametrize("crs", [
    {"type": "name", "properties": {"name": "urn:ogc:def:crs:OGC:1.3:CRS84"}},
    {"type": "name", "properties": {"name": "EPSG:4326"}},
])
def test_longitude_latitude_crs_is_refused(tmp_path, crs):
    path = write_map(tmp_path, crs=crs)
    with pytest.raises(MapError, match="is longitude/latitude"):
        load_map(path)


def test_degree_sized_workspace_is_refused(tmp_path):
    lonlat = [[11.57 + x * 1e-5, 48.13 + y * 1e-5] for x, y in BOUNDARY]
    path = write_map(tmp_path, [feature("boundary", "Polygon", [lonlat])])
    with pytest.raises(MapError, match="longitude/latitude degrees"):
        load_map(path)


def test_metric_crs_is_accepted(tmp_path):
    path = write_map(tmp_path, crs={"type": "name", "properties": {"name": "EPSG:32632"}})
    assert load_map(path).boundary.area == 200.0


@pytest.mark.parametrize("name", ["/etc/hostname", "../../../etc/hostname", "../outside.asc"])
def test_elevation_is_confined_to_the_maps_folder(tmp_path, name):
    folder = tmp_path / "maps"
    folder.mkdir()
    path = write_map(folder, elevation=name)
    with pytest.raises(MapError, match="must be a file in the map's folder"):
        load_map(path)


def test_origin_is_validated_and_stored(tmp_path):
    from orange_plan.world.geomap import Origin

    origin = {"lat_deg": 48.137, "lon_deg": 11.575, "alt_m": 520.0}
    assert load_map(write_map(tmp_path, origin=origin)).origin == Origin(48.137, 11.575, 520.0)
    assert load_map(write_map(tmp_path)).origin is None
    for bad, match in [({"lat_deg": 91, "lon_deg": 0, "alt_m": 0}, r"lat_deg = 91 must be"),
                       ({"lat_deg": 1, "lon_deg": 2}, "origin needs 'alt_m'"),
                       ({"lat": 1, "lon_deg": 2, "alt_m": 0}, "did you mean 'lat_deg'"),
                       ([48, 11], "'origin' must be")]:
        with pytest.raises(MapError, match=match):
            load_map(write_map(tmp_path, origin=bad))


# --- simulate -------------------------------------------------------------------------------
def test_simulate_clips_route_speeds_to_the_robot_and_says_so(tmp_path):
    scenario = write_scenario(tmp_path)  # v_min 0.2, v_max 1.0
    (tmp_path / "route.csv").write_text(ROUTE, encoding="utf-8")
    code, stdout, err = run_cli("simulate", scenario, tmp_path / "route.csv", "-o",
                                tmp_path / "r.csv", "--json")
    assert code == 0, err
    report = json.loads(stdout)
    assert report["speeds_clipped"] == 3
    import pandas as pd

    v = pd.read_csv(tmp_path / "r.csv")["v_mps"]
    assert v.max() <= 1.0 + 1e-9
    code, stdout, _ = run_cli("simulate", scenario, tmp_path / "route.csv", "-o", tmp_path / "r.csv")
    assert "3 route speed(s) outside the robot's [0.2, 1] m/s were clipped" in stdout


@pytest.mark.parametrize("option, value, needle", [
    ("--rate-hz", "1e5", "must be in (0, 1000] Hz"),
    ("--rate-hz", "nan", "--rate-hz must be a finite number"),
    ("--max-duration-s", "-1", "--max-duration-s must be a number > 0"),
    ("--max-duration-s", "inf", "--max-duration-s must be a finite number"),
])
def test_simulate_bad_rate_and_duration_are_exit_2(tmp_path, option, value, needle):
    scenario = write_scenario(tmp_path)
    (tmp_path / "route.csv").write_text(ROUTE, encoding="utf-8")
    code, _, err = run_cli("simulate", scenario, tmp_path / "route.csv", "-o",
                           tmp_path / "r.csv", option, value)
    assert code == 2 and needle in one_line(err)


# --- scenarios ------------------------------------------------------------------------------
def test_absurd_mass_is_one_line_without_raw_warnings(tmp_path):
    scenario = write_scenario(tmp_path, set={"robot.mass_kg": 1e308})
    code, stdout, err = run_cli("range", scenario, "--json")
    assert code == 2 and stdout == ""
    assert "too large to compute with" in one_line(err)


def test_exhausted_battery_is_said_so(tmp_path):
    scenario = write_scenario(tmp_path, set={"battery.cycles": 1e6})
    code, _, err = run_cli("range", scenario)
    assert code == 2 and "the battery is exhausted" in one_line(err)


def test_library_warnings_become_one_line_each(tmp_path):
    import warnings

    from orange_plan.cli import handles_errors

    @handles_errors
    def noisy(as_json=False):
        np.log(np.zeros(1))  # a raw numpy RuntimeWarning
        warnings.warn("something odd", UserWarning, stacklevel=1)

    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stderr(buf):
        noisy()
    lines = buf.getvalue().splitlines()
    assert lines == ["orange-plan: warning: RuntimeWarning: divide by zero encountered in log",
                     "orange-plan: warning: UserWarning: something odd"]


# --- predict and convert ----------------------------------------------------------------------
def test_predict_refuses_positions_far_off_the_map(tmp_path):
    scenario = write_scenario(tmp_path)
    rec = tmp_path / "rec.csv"
    rec.write_text("t_s,power_W,x_m,y_m\n0,10,1e6,1\n1,10,1e6,2\n2,10,1e6,3\n", encoding="utf-8")
    code, _, err = run_cli("predict", rec, "--scenario", scenario)
    assert code == 2 and "3 of 3 positions lie more than 10 m outside" in one_line(err)


def test_convert_json_stdout_stays_json_when_the_library_prints(tmp_path):
    log = write_ulog(tmp_path / "drive.ulg")
    # a data message for a subscription that does not exist: pyulog prints a warning
    log.write_bytes(log.read_bytes() + struct.pack("<HBH", 10, ord("D"), 7) + bytes(8))
    code, stdout, err = run_cli("convert", log, "-o", tmp_path / "r.csv", "--json")
    assert code == 0, err
    assert json.loads(stdout)["format"] == "ulog"
    assert "no subscription found" in err
