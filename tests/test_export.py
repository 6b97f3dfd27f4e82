"""Autopilot export: ENU <-> WGS84, waypoint decimation, the .plan and WPL 110 files read back.

The geodesy is checked against independent references: the textbook radii of curvature
(metres per degree of latitude M and of longitude N cos(lat) on the WGS84 ellipsoid) for
small offsets, and the exact round trip over a 2 km map. Waypoints are checked against the
tour itself: every tour vertex within 0.1 m of the waypoint polyline.
"""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import run_cli
from hypothesis import given, settings
from hypothesis import strategies as st
from planning_worlds import write_world

from orange_plan.context import load_context
from orange_plan.errors import InputError
from orange_plan.export.autopilot import (
    DO_CHANGE_SPEED,
    NAV_RETURN_TO_LAUNCH,
    NAV_TAKEOFF,
    NAV_WAYPOINT,
    WGS84_A_M,
    WGS84_E2,
    build_mission,
    enu_to_geodetic,
    latlon_to_xy,
    read_items,
    waypoint_indices,
)
from orange_plan.planning.tour import plan_tour
from orange_plan.sim.route import load_route

MUNICH = SimpleNamespace(lat_deg=48.137, lon_deg=11.575, alt_m=520.0)


def with_origin(scenario_path, origin=MUNICH):
    """Add an ``origin`` to the map of a planning_worlds scenario."""
    map_path = scenario_path.with_suffix(".geojson")
    data = json.loads(map_path.read_text())
    data["origin"] = {"lat_deg": origin.lat_deg, "lon_deg": origin.lon_deg,
                      "alt_m": origin.alt_m}
    map_path.write_text(json.dumps(data))
    return scenario_path


def distance_to_polyline(points, line) -> np.ndarray:
    a, b = line[:-1], line[1:]
    ab = b - a
    out = []
    for p in points:
        t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab),
                                                                   1e-18), 0, 1)
        out.append(np.min(np.hypot(*(p - (a + t[:, None] * ab)).T)))
    return np.asarray(out)


# --- geodesy ------------------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(lat=st.floats(-80, 80), lon=st.floats(-180, 180), alt=st.floats(-400, 5000),
       x=st.floats(-2000, 2000), y=st.floats(-2000, 2000))
def test_round_trip_is_exact_over_a_2km_map(lat, lon, alt, x, y):
    origin = SimpleNamespace(lat_deg=lat, lon_deg=lon, alt_m=alt)
    la, lo, _ = enu_to_geodetic(origin, x, y)
    bx, by = latlon_to_xy(origin, la, lo)
    assert math.hypot(bx - x, by - y) < 1e-3  # the files need 0.1 m


@settings(max_examples=100, deadline=None)
@given(lat=st.floats(-80, 80), lon=st.floats(-180, 180), dx=st.floats(-10, 10),
       dy=st.floats(-10, 10))
def test_small_offsets_match_the_radii_of_curvature(lat, lon, dx, dy):
    """Independent reference: near the origin, dlat = dy / M and dlon = dx / (N cos lat)."""
    origin = SimpleNamespace(lat_deg=lat, lon_deg=lon, alt_m=0.0)
    la, lo, h = enu_to_geodetic(origin, dx, dy)
    s2 = math.sin(math.radians(lat)) ** 2
    m = WGS84_A_M * (1 - WGS84_E2) / (1 - WGS84_E2 * s2) ** 1.5
    n = WGS84_A_M / math.sqrt(1 - WGS84_E2 * s2)
    dlon = (lo - lon + 180.0) % 360.0 - 180.0  # across the antimeridian lon wraps to -180
    east = math.radians(dlon) * n * math.cos(math.radians(lat))
    north = math.radians(la - lat) * m
    assert east == pytest.approx(dx, abs=2e-3) and north == pytest.approx(dy, abs=2e-3)
    assert abs(h) < 1e-4  # the tangent plane touches the ellipsoid at the origin


def test_known_point_one_km_north():
    """One kilometre north of 48.137 deg N is 0.008993 deg of latitude (M = 6,366 km there)."""
    la, lo, _ = enu_to_geodetic(MUNICH, 0.0, 1000.0)
    assert la - MUNICH.lat_deg == pytest.approx(1000.0 / 111_215.0 * 1.0, rel=2e-3)
    assert lo == pytest.approx(MUNICH.lon_deg, abs=1e-12)


# --- decimation ---------------------------------------------------------------------------------


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 200), wiggle=st.floats(0, 0.3))
def test_decimated_waypoints_stay_within_0p1m_of_the_tour(seed, n, wiggle):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, n)
    xy = np.c_[200 * t, 30 * np.sin(6 * t)] + rng.normal(0, wiggle, (n, 2))
    speed = np.round(rng.choice([0.5, 0.5, 0.5, 0.8], n), 3)
    keep = waypoint_indices(xy, speed)
    assert keep[0] == 0 and keep[-1] == n - 1 and np.all(np.diff(keep) > 0)
    assert np.all(distance_to_polyline(xy, xy[keep]) <= 0.1 + 1e-9)
    # every speed change is a waypoint: the commanded speed of each segment is the plan's
    commanded = np.repeat(speed[keep[:-1]], np.diff(keep))
    assert np.all(np.abs(commanded - speed[:-1]) <= 0.01 + 1e-12)


def test_straight_lines_collapse_to_their_ends():
    xy = np.c_[np.linspace(0, 100, 51), np.zeros(51)]
    assert waypoint_indices(xy, np.full(51, 0.7)).tolist() == [0, 50]
    speed = np.r_[np.full(25, 0.7), np.full(26, 1.0)]
    assert waypoint_indices(xy, speed).tolist() == [0, 25, 50]


# --- files --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    folder = tmp_path_factory.mktemp("export")
    scenario = with_origin(write_world(folder, width_m=30.0, height_m=20.0,
                                       obstacles=[(12, 4, 16, 12)], rated_energy_Wh=0.6))
    ctx = load_context(scenario)
    plan = plan_tour(ctx, n_vertices=300, seed=0, max_candidates=60, bitstar_legs=0)
    path = plan.write(folder / "plan.geojson")
    return scenario, path, ctx, plan


@pytest.mark.parametrize("fmt, name", [("qgc", "mission.plan"), ("mavlink", "mission.waypoints")])
def test_export_files_read_back_within_0p1m(planned, tmp_path, fmt, name):
    scenario, plan_path, ctx, _ = planned
    out = tmp_path / name
    code, stdout, stderr = run_cli("export", plan_path, "--scenario", scenario, "--format", fmt,
                                   "-o", out, "--json")
    assert code == 0, stderr
    report = json.loads(stdout)
    assert report["waypoints"] <= report["tour_vertices"]
    home, items = read_items(out)
    origin = ctx.world.map.origin
    hx, hy = latlon_to_xy(origin, home[0], home[1])
    assert math.hypot(hx - 2.0, hy - 2.0) < 0.1 and home[2] == pytest.approx(origin.alt_m)
    commands = [it.command for it in items]
    assert commands[0] == DO_CHANGE_SPEED and commands[-1] == NAV_RETURN_TO_LAUNCH
    assert NAV_TAKEOFF not in commands  # a ground robot
    wp = np.array([latlon_to_xy(origin, it.params[4], it.params[5]) for it in items
                   if it.command == NAV_WAYPOINT])
    route = load_route(plan_path)
    # positions: each waypoint is a tour vertex (within 0.1 m), the last is home
    assert np.all(np.min(np.hypot(*(wp[:, None, :] - route.xy_m[None]).transpose(2, 0, 1)),
                         axis=1) < 0.1)
    assert np.hypot(*(wp[-1] - np.array([2.0, 2.0]))) < 0.1
    # path: every tour vertex within 0.1 m of the flown polyline (start, waypoints)
    flown = np.vstack([route.xy_m[:1], wp])
    assert np.all(distance_to_polyline(route.xy_m, flown) <= 0.1)
    # speeds: the speed in force on each waypoint's arriving segment is the plan's
    speed, seg = None, 0
    legs = np.cumsum(np.hypot(*np.diff(route.xy_m, axis=0).T))
    for it in items:
        if it.command == DO_CHANGE_SPEED:
            assert it.params[0] == 1  # ground speed
            speed = it.params[1]
        elif it.command == NAV_WAYPOINT:
            assert it.frame == 3 and it.params[6] == 0.0
            assert speed is not None
            assert abs(speed - route.speed_mps[seg]) <= 0.01 + 1e-9
            i = int(np.argmin(np.hypot(*(route.xy_m - wp[0]).T)))
            seg = min(i, len(legs) - 1)
            wp = wp[1:]
    if fmt == "qgc":
        data = json.loads(out.read_text())
        assert data["fileType"] == "Plan" and data["version"] == 1
        mission = data["mission"]
        assert mission["vehicleType"] == 10 and mission["firmwareType"] == 12
        assert all(it["type"] == "SimpleItem" and len(it["params"]) == 7 for it in mission["items"])
        assert [it["doJumpId"] for it in mission["items"]] == list(range(1, len(items) + 1))
        fences = data["geoFence"]["polygons"]
        assert [f["inclusion"] for f in fences] == [True, False]
        assert data["rallyPoints"]["points"] == []
    else:
        lines = out.read_text().splitlines()
        assert lines[0] == "QGC WPL 110"
        assert all(len(line.split("\t")) == 12 for line in lines[1:])
        assert lines[1].split("\t")[:4] == ["0", "1", "0", "16"]


def test_aerial_gets_a_takeoff_and_needs_an_altitude(planned):
    _, plan_path, ctx, _ = planned
    route = load_route(plan_path)
    mission = build_mission(ctx.world, "aerial", route.xy_m, route.speed_mps, altitude_m=25.0)
    assert mission.items[0].command == NAV_TAKEOFF and mission.items[0].params[6] == 25.0
    assert all(it.params[6] == 25.0 for it in mission.items if it.command == NAV_WAYPOINT)
    with pytest.raises(InputError, match="altitude"):
        build_mission(ctx.world, "aerial", route.xy_m, route.speed_mps)


def test_map_without_origin_is_one_line_exit_2(tmp_path):
    scenario = write_world(tmp_path, width_m=30.0, height_m=20.0, rated_energy_Wh=0.6)
    plan = tmp_path / "p.geojson"
    plan.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"kind": "tour", "speed_mps": [1.0, 1.0, 1.0]},
         "geometry": {"type": "LineString", "coordinates": [[2, 2], [10, 2], [2, 2]]}}]}))
    code, _, stderr = run_cli("export", plan, "--scenario", scenario, "-o", tmp_path / "m.plan")
    assert code == 2
    assert "origin" in stderr and len(stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("args, message", [
    (["--format", "kml", "-o", "m.plan"], "format"),
    (["--format", "qgc", "-o", "m.txt"], ".plan"),
])
def test_bad_format_or_name_is_refused(planned, tmp_path, args, message):
    scenario, plan_path, _, _ = planned
    args = [tmp_path / a if a.startswith("m.") else a for a in args]
    code, _, stderr = run_cli("export", plan_path, "--scenario", scenario, *args)
    assert code == 2 and message in stderr


def test_bad_origin_is_refused(tmp_path):
    scenario = with_origin(write_world(tmp_path), SimpleNamespace(lat_deg=95.0, lon_deg=0.0,
                                                                  alt_m=0.0))
    with pytest.raises(InputError, match="lat_deg"):
        load_context(scenario)


def test_plan_made_on_another_map_is_refused(planned, tmp_path):
    """The tour of a 30 m x 20 m world, exported with a map whose free space it leaves."""
    _, plan_path, _, _ = planned
    other = with_origin(write_world(tmp_path, width_m=30.0, height_m=20.0,
                                    obstacles=[(4, 0.5, 26, 19.5)], rated_energy_Wh=0.6))
    code, _, stderr = run_cli("export", plan_path, "--scenario", other, "-o", tmp_path / "m.plan")
    assert code == 2 and len(stderr.strip().splitlines()) == 1
    assert "route vertex" in stderr and "this scenario's map" in stderr
    assert not (tmp_path / "m.plan").exists()


@pytest.mark.parametrize("name, text", [
    ("rec.csv", "t_s,power_W,x_m,y_m\n0,5,2,2\n1,5,10,2\n2,5,2,2\n"),  # a recording
    ("route.csv", "x_m,y_m,speed_mps\n2,2,1\n10,2,1\n2,2,1\n"),  # a route, not a plan
])
def test_only_a_plan_geojson_is_exported(planned, tmp_path, name, text):
    scenario, _, _, _ = planned
    (tmp_path / name).write_text(text, encoding="utf-8")
    code, _, stderr = run_cli("export", tmp_path / name, "--scenario", scenario, "-o",
                              tmp_path / "m.plan")
    assert code == 2 and "plan GeoJSON" in stderr and len(stderr.strip().splitlines()) == 1


def test_waypoints_and_plan_leave_the_yaw_alike(planned, tmp_path):
    """Keep the heading in both files: null in the .plan, NaN in the WPL (0 = face north)."""
    scenario, plan_path, _, _ = planned
    files = {fmt: tmp_path / name for fmt, name in (("qgc", "m.plan"),
                                                    ("mavlink", "m.waypoints"))}
    for fmt, path in files.items():
        code, _, stderr = run_cli("export", plan_path, "--scenario", scenario, "--format", fmt,
                                  "-o", path)
        assert code == 0, stderr
    (_, qgc), (_, wpl) = read_items(files["qgc"]), read_items(files["mavlink"])
    assert [it.command for it in qgc] == [it.command for it in wpl]
    for a, b in zip(qgc, wpl):
        assert np.array_equal(np.isnan(a.params), np.isnan(b.params))
    yaws = [it.params[3] for it in wpl if it.command == NAV_WAYPOINT]
    assert yaws and all(math.isnan(y) for y in yaws)
