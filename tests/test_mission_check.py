"""Mission check: missions read from QGroundControl / MAVLink / CSV / GeoJSON files, each leg
flown and charged by the scenario's model, margins, verdict and point of no return.

The round trip export -> check is held to the plan's own energies (1 %) with corners flown as
the plan models them; hand-made files in QGroundControl's own format are read item by item;
malformed missions are refused in one line (exit 2). The invariants (energies >= 0, energy
used increasing, margin arithmetic, verdict and point of no return consistent with the
margins) are properties over random missions; a level leg and a vertical climb are checked
against hand-computed energies.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import replace

import numpy as np
import pytest
import tomli_w
from conftest import run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from planning_worlds import write_world
from test_export import MUNICH, with_origin

from orange_plan.context import load_context
from orange_plan.errors import InputError
from orange_plan.export.autopilot import build_mission, enu_to_geodetic, write_mission
from orange_plan.export.missions_in import read_mission
from orange_plan.physics.terms import G_MPS2
from orange_plan.planning.mission_check import (
    Mission,
    MissionWaypoint,
    check_mission,
)
from orange_plan.planning.tour import plan_tour

pytestmark = pytest.mark.timeout(600)


def make_aerial(path, **robot):
    """Turn a ``write_world`` scenario into a small quadrotor's."""
    data = tomllib.loads(path.read_text())
    data["robot"].update({"kind": "aerial", "crr": 0.0, "mass_kg": 1.0, "hover_W": 40.0,
                          "v_max_mps": 5.0, "accel_max_mps2": 2.0,
                          "drag_coeff_kg_per_m": 0.04, **robot})
    path.write_text(tomli_w.dumps(data))
    return path


@pytest.fixture(scope="module")
def ground(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ground")
    scenario = with_origin(write_world(folder, width_m=30.0, height_m=20.0,
                                       obstacles=[(12, 4, 16, 12)], rated_energy_Wh=0.6))
    ctx = load_context(scenario)
    plan = plan_tour(ctx, n_vertices=300, seed=0, max_candidates=60, bitstar_legs=0)
    plan.write(folder / "plan.geojson")
    return folder, scenario, ctx, plan


@pytest.fixture(scope="module")
def aerial(tmp_path_factory):
    folder = tmp_path_factory.mktemp("aerial")
    scenario = make_aerial(with_origin(write_world(folder, width_m=60.0, height_m=40.0,
                                                   obstacles=[(20, 10, 28, 24)],
                                                   rated_energy_Wh=2.0)))
    ctx = load_context(scenario)
    plan = plan_tour(ctx, n_vertices=300, seed=0, max_candidates=60, bitstar_legs=0)
    plan.write(folder / "plan.geojson")
    return folder, scenario, ctx, plan


# --- round trip: export -> check gives the plan's own energies --------------------------------


@pytest.mark.parametrize("which", ["ground", "aerial"])
@pytest.mark.parametrize("fmt, name", [("qgc", "m.plan"), ("mavlink", "m.waypoints")])
def test_export_then_check_gives_the_plans_energy_within_1pct(request, which, fmt, name):
    folder, scenario, _ctx, plan = request.getfixturevalue(which)
    altitude = 15.0 if which == "aerial" else None
    args = ["--altitude-m", "15"] if altitude else []
    code, _, err = run_cli("export", folder / "plan.geojson", "--scenario", scenario,
                           "-o", folder / name, "--format", fmt, *args)
    assert code == 0, err
    # corners flown as the plan models them (no slowing): the same motion, the same energy
    code, text, err = run_cli("check", folder / name, "--scenario", scenario,
                              "--corners-as-planned", "--json")
    assert code == 0, err
    report = json.loads(text)
    legs = [leg for leg in report["legs"] if leg["kind"] == "leg"]
    planned = plan.summary["energy_planned_J"]
    assert sum(leg["energy_J"] for leg in legs) == pytest.approx(planned, rel=0.01)
    # used at each waypoint: the plan's energy at the same tour vertex
    used = {tuple(np.round(leg["to_xyz_m"][:2], 3)): leg["energy_used_J"] for leg in legs}
    offset = report["legs"][0]["energy_J"] if which == "aerial" else 0.0  # the take-off
    for xy, e in zip(np.round(plan.xy_m, 3), plan.energy_used_J):
        if tuple(xy) in used and e > 0.2 * planned:
            assert used[tuple(xy)] - offset == pytest.approx(e, rel=0.01)
    kinds = [leg["kind"] for leg in report["legs"]]
    assert kinds == (["takeoff", *["leg"] * len(legs), "landing"] if altitude
                     else ["leg"] * len(legs))
    if altitude:
        assert report["legs"][0]["climb_m"] == pytest.approx(15.0, abs=0.01)


@pytest.mark.parametrize("which", ["ground", "aerial"])
def test_the_plan_file_itself_checks_to_its_own_energy(request, which):
    folder, _scenario, ctx, plan = request.getfixturevalue(which)
    result = check_mission(read_mission(folder / "plan.geojson"), ctx)
    assert result.energy_J == pytest.approx(plan.summary["energy_planned_J"], rel=0.01)
    assert result.duration_s == pytest.approx(plan.summary["duration_s"], rel=0.01)


def test_slowing_for_corners_costs_energy(aerial):
    """The autopilot's acceptance radius turns corners on arcs it must slow down for: the
    mission costs more than the plan's corner-blind figure."""
    folder, _scenario, ctx, plan = aerial
    mission = build_mission(ctx.world, "aerial", plan.xy_m, plan.speed_mps, altitude_m=15.0)
    write_mission(mission, folder / "corners.plan", "qgc")
    origin = ctx.world.map.origin
    slow = check_mission(read_mission(folder / "corners.plan", origin, 2.0), ctx)
    wide = check_mission(read_mission(folder / "corners.plan", origin, 5.0), ctx)
    blind = check_mission(read_mission(folder / "corners.plan", origin, math.inf), ctx)
    assert slow.energy_J > wide.energy_J > blind.energy_J
    assert slow.duration_s > wide.duration_s > blind.duration_s


# --- hand-made files in QGroundControl's own format -------------------------------------------


def latlon(x, y):
    lat, lon, _ = enu_to_geodetic(MUNICH, x, y)
    return float(lat), float(lon)


def qgc_item(command, params, frame=3, seq=1):
    return {"type": "SimpleItem", "command": command, "frame": frame, "params": params,
            "autoContinue": True, "doJumpId": seq, "AMSLAltAboveTerrain": None,
            "Altitude": params[6], "AltitudeMode": 1}


def qgc_file(items, home=(2.0, 2.0), vehicle=2, extra=None):
    """A .plan as QGroundControl 4 saves it (its own keys, nulls for unused params)."""
    lat, lon = latlon(*home)
    mission = {"cruiseSpeed": 15, "firmwareType": 12, "globalPlanAltitudeMode": 1,
               "hoverSpeed": 4, "items": items,
               "plannedHomePosition": [lat, lon, MUNICH.alt_m], "vehicleType": vehicle,
               "version": 2}
    mission.update(extra or {})
    return {"fileType": "Plan", "geoFence": {"circles": [], "polygons": [], "version": 2},
            "groundStation": "QGroundControl", "mission": mission,
            "rallyPoints": {"points": [], "version": 2}, "version": 1}


def waypoint(x, y, alt, hold=0.0, radius=0.0):
    return qgc_item(16, [hold, radius, 0, None, *latlon(x, y), alt])


def test_a_hand_made_qgc_plan_is_read_item_by_item(aerial):
    folder, _scenario, ctx, _ = aerial
    items = [qgc_item(22, [0, 0, 0, None, *latlon(2, 2), 12]),
             qgc_item(178, [1, 3.0, -1, 0, 0, 0, 0], frame=2),
             waypoint(40, 5, 12, hold=4.0),
             qgc_item(206, [5, 0, 1, 0, 0, 0, 0], frame=2),  # camera trigger: no motion
             waypoint(40, 30, 20, radius=3.0),
             qgc_item(20, [0, 0, 0, 0, 0, 0, 0], frame=2)]
    path = folder / "hand.plan"
    path.write_text(json.dumps(qgc_file(items)))
    mission = read_mission(path, ctx.world.map.origin)
    assert mission.takeoff_alt_m == 12
    assert mission.returns_home
    wps = mission.waypoints
    assert len(wps) == 3
    assert (wps[1].x_m, wps[1].y_m) == pytest.approx((40, 5), abs=1e-6)
    assert (wps[2].z_m, wps[1].stay_s, wps[2].corner_radius_m) == (20, 4.0, None)
    assert wps[1].corner_radius_m == 2.0  # param2 = 0: the autopilot's default
    assert wps[0].speed_mps == wps[1].speed_mps == 3.0  # hover speed, then DO_CHANGE_SPEED
    result = check_mission(mission, ctx)
    kinds = [leg.kind for leg in result.legs]
    assert kinds == ["takeoff", "leg", "leg", "return", "landing"]
    assert result.legs[1].duration_s > 4.0 + 38 / 3.0  # the hold and the leg at 3 m/s


def test_a_wpl_file_with_sea_level_altitudes(aerial):
    folder, _scenario, ctx, _ = aerial
    rows = ["QGC WPL 110"]
    home = (*latlon(2, 2), MUNICH.alt_m)
    rows.append("\t".join(map(str, [0, 1, 0, 16, 0, 0, 0, 0, *home, 1])))
    rows.append("\t".join(map(str, [1, 0, 0, 22, 0, 0, 0, 0, *latlon(2, 2),
                                    MUNICH.alt_m + 10, 1])))
    rows.append("\t".join(map(str, [2, 0, 0, 16, 0, 0, 0, "nan", *latlon(30, 30),
                                    MUNICH.alt_m + 10, 1])))
    rows.append("\t".join(map(str, [3, 0, 2, 20, 0, 0, 0, 0, 0, 0, 0, 1])))
    path = folder / "hand.waypoints"
    path.write_text("\n".join(rows) + "\n")
    mission = read_mission(path, ctx.world.map.origin)
    assert mission.takeoff_alt_m == pytest.approx(10.0)
    assert mission.waypoints[1].z_m == pytest.approx(10.0)
    assert (mission.waypoints[1].x_m, mission.waypoints[1].y_m) == pytest.approx((30, 30),
                                                                                 abs=1e-6)


# --- malformed missions: one line, exit 2 ------------------------------------------------------


MALFORMED = {
    "unknown_command": ([waypoint(20, 5, 10), qgc_item(31000, [0] * 7, frame=2)], {},
                        "unknown or unsupported MAV_CMD 31000"),
    "missing_home": ([waypoint(20, 5, 10)], {"plannedHomePosition": None}, "missing home"),
    "nan_coordinate": ([qgc_item(16, [0, 0, 0, None, None, 11.575, 10])], {},
                       "is not a number"),
    "below_ground": ([waypoint(20, 5, -5)], {}, "below the ground"),
    "off_the_map": ([qgc_item(16, [0, 0, 0, None, 48.2, 11.575, 10])], {},
                    "outside the map"),
    "complex_item": ([{"type": "ComplexItem", "complexItemType": "survey"}], {},
                     "complex item"),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_missions_get_one_line_and_exit_2(aerial, tmp_path, case):
    _, scenario, _, _ = aerial
    items, extra, message = MALFORMED[case]
    path = tmp_path / "bad.plan"
    path.write_text(json.dumps(qgc_file(items, extra=extra)))
    code, _, err = run_cli("check", path, "--scenario", scenario)
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert message in err


@pytest.mark.parametrize("text, message", [
    ("QGC WPL 110\n", "missing home"),
    ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\tnan\t11.5\t520\t1\n1\t0\t3\t16\t0\t0\t0\t0\t48.1"
     "\t11.5\t10\t1\n", "missing home"),
    ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t48.137\t11.575\t520\t1\n1\t0\t3\t16\t0\t0\t0\t0\t"
     "nan\t11.575\t10\t1\n", "is not a number"),
    ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t48.137\t11.575\t520\t1\n1\t0\t0\t16\t0\t0\t0\t0\t"
     "48.1371\t11.575\t500\t1\n", "below the ground"),
    ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t48.137\t11.575\t520\t1\n1\t0\t3\t84\t0\t0\t0\t0\t"
     "48.1371\t11.575\t10\t1\n", "MAV_CMD 84"),
])
def test_malformed_wpl_files_get_one_line_and_exit_2(aerial, tmp_path, text, message):
    _, scenario, _, _ = aerial
    path = tmp_path / "bad.waypoints"
    path.write_text(text)
    code, _, err = run_cli("check", path, "--scenario", scenario)
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert message in err


@pytest.mark.parametrize("text, message", [
    ("x_m,y_m\n2,2\nnan,3\n", "row 2: x_m is not a number"),
    ("x_m,y_m,speed_mps\n2,2,1\n5,5,-1\n", "must be >= 0.01"),
    ("x_m,y_m\n2,2\n5000,5\n", "outside the map"),
    ("x_m,y_m\n2,2\n", "at least one waypoint"),
])
def test_malformed_route_csv_gets_one_line_and_exit_2(ground, tmp_path, text, message):
    _, scenario, _, _ = ground
    path = tmp_path / "route.csv"
    path.write_text(text)
    code, _, err = run_cli("check", path, "--scenario", scenario)
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert message in err


@pytest.mark.parametrize("wind", ["6", "x@270", "6@nan", "-1@90", "500@90"])
def test_bad_wind_is_refused(ground, tmp_path, wind):
    folder, scenario, _, _ = ground
    code, _, err = run_cli("check", folder / "plan.geojson", "--scenario", scenario,
                           "--wind", wind)
    assert code == 2 and "--wind" in err


# --- hand-computed energies ---------------------------------------------------------------------


def test_a_level_leg_costs_power_times_time(ground):
    """Rolling force is the same at any speed, so energy = ancillary power x time + rolling
    force x distance, whatever the ramps (no drag, duty cycle 1, flat ground)."""
    _, _, ctx, _ = ground
    sc = replace(ctx.scenario, mission=replace(ctx.scenario.mission, duty_cycle=1.0))
    model = ctx.model.with_theta({"drag_kg_per_m": 0.0})
    flat = replace(ctx.with_scenario(sc), model=model)
    mission = Mission((MissionWaypoint(2, 1), MissionWaypoint(28, 1, speed_mps=None)),
                      returns_home=False)
    result = check_mission(mission, flat)
    leg = result.legs[0]
    anc = sc.ancillary_power_W
    rolling = model.coefficient("rolling_kg") * G_MPS2 * sc.robot.crr
    assert leg.energy_J == pytest.approx(anc * leg.duration_s + rolling * 26.0, rel=2e-3)
    v, a = leg.speed_mps, sc.robot.accel_max_mps2
    assert leg.duration_s == pytest.approx(26.0 / v + v / a, abs=0.5)


def test_a_vertical_climb_costs_hover_time_plus_potential_energy(aerial):
    _, _, ctx, _ = aerial
    sc = ctx.scenario
    hx, hy = ctx.world.home_xy_m
    mission = Mission((MissionWaypoint(hx, hy), MissionWaypoint(hx + 10, hy, 20.0, stay_s=30)),
                      takeoff_alt_m=20.0)
    result = check_mission(mission, ctx)
    climb = result.legs[0]
    assert climb.kind == "takeoff" and climb.climb_m == 20.0
    power = sc.ancillary_power_W  # hover included
    weight = ctx.model.coefficient("grade_kg") * G_MPS2
    assert climb.energy_J == pytest.approx(power * climb.duration_s + weight * 20.0, rel=2e-3)
    hold = result.legs[1]  # a 10 m leg, then 30 s hovering
    assert hold.duration_s > 30.0
    assert result.legs[-1].kind == "landing" and result.legs[-1].climb_m == -20.0


# --- properties over random missions ------------------------------------------------------------


@st.composite
def missions(draw, aerial_robot: bool):
    n = draw(st.integers(1, 6))
    pts = [MissionWaypoint(2.0, 2.0, 0.0)]
    for _ in range(n):
        pts.append(MissionWaypoint(
            draw(st.floats(0.0, 30.0)), draw(st.floats(0.0, 20.0)),
            draw(st.floats(0.0, 30.0)) if aerial_robot else 0.0,
            draw(st.one_of(st.none(), st.floats(0.3, 5.0))),
            draw(st.sampled_from([0.0, 0.0, 3.0])),
            draw(st.one_of(st.none(), st.floats(0.0, 10.0), st.just(math.inf)))))
    takeoff = draw(st.one_of(st.none(), st.floats(0.0, 30.0))) if aerial_robot else None
    return Mission(tuple(pts), takeoff, draw(st.booleans()))


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    folder = tmp_path_factory.mktemp("small")
    ground_ctx = load_context(write_world(folder, width_m=30.0, height_m=20.0, name="g",
                                          ramp=0.05, rated_energy_Wh=0.3))
    aerial_ctx = load_context(make_aerial(write_world(folder, width_m=30.0, height_m=20.0,
                                                      name="a", rated_energy_Wh=0.4)))
    return {"ground": ground_ctx, "aerial": aerial_ctx}


def check_invariants(result, ctx):
    legs = result.legs
    energy = np.array([leg.energy_J for leg in legs])
    used = np.array([leg.energy_used_J for leg in legs])
    home = np.array([leg.energy_to_home_J for leg in legs])
    reserve = np.array([leg.reserve_J for leg in legs])
    margin = result.margin_J
    assert np.all(energy >= 0) and np.all(home >= 0) and np.all(reserve >= 0)
    assert np.all(np.diff(used) >= 0)
    assert used == pytest.approx(np.cumsum(energy))
    assert result.energy_J == pytest.approx(used[-1])
    assert margin == pytest.approx(result.energy_available_J - used - home - reserve)
    assert home[-1] == 0.0
    if result.verdict == "fits":
        assert np.all(margin >= 0) and result.first_failing_waypoint is None
    elif result.verdict == "fits_without_reserve":
        assert np.any(margin < 0) and np.all(margin + reserve >= 0)
        assert result.first_failing_waypoint == legs[int(np.argmax(margin < 0))].to_waypoint
    else:
        assert np.any(margin + reserve < 0)
        assert result.first_failing_waypoint == legs[int(np.argmax(margin + reserve < 0))
                                                     ].to_waypoint
    pnr = result.point_of_no_return
    distance = np.array([leg.distance_m for leg in legs])
    if pnr is None:
        assert result.start_margin_J < 0
        return
    before = distance < pnr[1] - 1e-9
    assert np.all(margin[before] >= 0)  # every leg end before it keeps its margin
    if result.verdict == "fits":
        assert pnr[1] == pytest.approx(distance[-1])
    else:
        k = int(np.argmax(margin < 0))  # the first leg whose end has no margin holds it
        assert distance[k] - legs[k].length_m - 1e-6 <= pnr[1] <= distance[k] + 1e-6
        assert pnr[0] == legs[k].from_waypoint


@pytest.mark.parametrize("kind", ["ground", "aerial"])
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_check_invariants_hold_on_random_missions(small, kind, data):
    ctx = small[kind]
    mission = data.draw(missions(kind == "aerial"))
    try:
        result = check_mission(mission, ctx)
    except InputError as exc:  # every waypoint at home: nothing to fly
        assert "nothing to fly" in str(exc)
        return
    check_invariants(result, ctx)


def test_worst_wind_is_the_costliest_direction(small):
    ctx = small["aerial"]
    mission = Mission((MissionWaypoint(2, 2), MissionWaypoint(28, 2, 10.0, corner_radius_m=5),
                       MissionWaypoint(28, 18, 10.0)), takeoff_alt_m=10.0)
    result = check_mission(mission, ctx, wind=(0.0, -4.0), worst_wind=True)
    from_deg, energy = result.worst_wind
    for probe in (0.0, 90.0, 180.0, 270.0):
        wx, wy = -4.0 * math.sin(math.radians(probe)), -4.0 * math.cos(math.radians(probe))
        assert check_mission(mission, ctx, wind=(wx, wy)).energy_J <= energy + 1e-6
    assert 0.0 <= from_deg < 360.0


def test_the_figure_is_written(aerial, tmp_path):
    folder, scenario, _, _ = aerial
    png = tmp_path / "check.png"
    code, text, err = run_cli("check", folder / "plan.geojson", "--scenario", scenario,
                              "--png", png)
    assert code == 0, err
    assert png.stat().st_size > 10_000
    assert "verdict" in text


def test_a_corner_too_tight_to_fly_is_a_stop(small):
    """A corner radius of 1e-300 m allowed 1e-150 m/s through the turn: the Driver crawled
    without end (found by the invariants property). Slower than a creep is a stop."""
    ctx = small["ground"]

    def mission(radius):
        return Mission((MissionWaypoint(2, 2), MissionWaypoint(20, 2, corner_radius_m=radius),
                        MissionWaypoint(20, 15)), returns_home=False)

    tight = check_mission(mission(1e-300), ctx)
    assert tight.energy_J == pytest.approx(check_mission(mission(None), ctx).energy_J)


def test_a_geojson_linestring_in_longitude_latitude(aerial, tmp_path):
    _, scenario, ctx, _ = aerial
    coords = [[*latlon(x, y)[::-1], z] for x, y, z in ((2, 2, 0), (30, 5, 12), (30, 30, 12))]
    path = tmp_path / "line.geojson"
    path.write_text(json.dumps({"type": "Feature", "properties": {},
                                "geometry": {"type": "LineString", "coordinates": coords}}))
    mission = read_mission(path, ctx.world.map.origin)
    assert mission.xyz_m == pytest.approx(np.array([[2, 2, 0], [30, 5, 12], [30, 30, 12]]),
                                          abs=1e-6)
    assert all(w.corner_radius_m is None for w in mission.waypoints)  # a normal mission
    code, text, err = run_cli("check", path, "--scenario", scenario, "--json")
    assert code == 0, err
    assert [leg["kind"] for leg in json.loads(text)["legs"]] == ["leg", "leg", "return",
                                                                "landing"]


def test_without_an_origin_the_mission_is_checked_in_a_frame_at_its_home(tmp_path):
    scenario = write_world(tmp_path, width_m=30.0, height_m=20.0)  # its map has no origin
    items = [waypoint(40, 2, 0), waypoint(40, 30, 0)]  # metres from MUNICH's (2, 2)
    path = tmp_path / "far.plan"
    path.write_text(json.dumps(qgc_file(items, vehicle=10)))
    code, text, err = run_cli("check", path, "--scenario", scenario, "--json")
    assert code == 0, err
    report = json.loads(text)
    assert report["in_map_frame"] is False
    first = report["legs"][0]
    assert first["from_xyz_m"] == pytest.approx([0.0, 0.0, 0.0], abs=1e-6)
    assert first["to_xyz_m"][:2] == pytest.approx([38.0, 0.0], abs=1e-3)


def test_a_scenario_serves_as_well_as_its_context(small):
    ctx = small["aerial"]
    mission = Mission((MissionWaypoint(2, 2), MissionWaypoint(20, 10, 10.0)), takeoff_alt_m=5.0)
    assert check_mission(mission, ctx.scenario).as_dict() == check_mission(mission,
                                                                            ctx).as_dict()


def test_a_hold_at_a_repeated_waypoint_counts(small):
    """A waypoint given twice (a hold written as a second, identical waypoint) had its hold
    dropped with the empty leg."""
    ctx = small["ground"]
    once = Mission((MissionWaypoint(2, 2), MissionWaypoint(20, 2, stay_s=10.0)),
                   returns_home=False)
    twice = Mission((MissionWaypoint(2, 2), MissionWaypoint(20, 2),
                     MissionWaypoint(20, 2, stay_s=10.0)), returns_home=False)
    assert check_mission(twice, ctx).duration_s == pytest.approx(
        check_mission(once, ctx).duration_s)


@settings(max_examples=30, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(turn_deg=st.floats(10.0, 170.0), radius=st.floats(0.2, 20.0), speed=st.floats(1.0, 5.0))
def test_the_robot_turns_a_corner_at_most_at_the_arcs_speed(small, turn_deg, radius, speed):
    """At a corner of heading change theta and radius r the robot is at most
    ``sqrt(accel_max r / tan(theta / 2))`` (one sample's acceleration of slack) where the legs
    meet: the last sample of the first leg and the first of the next."""
    from orange_plan.physics.pathcost import max_step_m
    from orange_plan.planning.mission_motion import drive
    from orange_plan.planning.mission_stages import mission_stages, robot_limits, with_corners

    ctx = small["aerial"]
    theta = math.radians(turn_deg)
    corner = (15.0, 2.0)
    after = (corner[0] + 12 * math.cos(theta), corner[1] + 12 * math.sin(theta))
    mission = Mission((MissionWaypoint(2.0, 2.0, 10.0, speed),
                       MissionWaypoint(*corner, 10.0, speed, 0.0, radius),
                       MissionWaypoint(*after, 10.0)), returns_home=False)
    robot = robot_limits(ctx)
    stages = with_corners(mission_stages(mission, robot), mission, robot)
    samples = drive([(None, stages)], ctx.world, robot, ctx.conditions,
                     max_step_m(ctx.world))
    a, dt = robot.accel_mps2, 0.1
    allowed = math.sqrt(a * radius / math.tan(theta / 2))
    leg = next(k for k, s in enumerate(stages) if s.kind == "leg")
    v = np.asarray(samples.state.speed_mps)
    at_corner = [np.flatnonzero(samples.label == leg)[-1],
                 np.flatnonzero(samples.label == leg + 1)[0]]
    assert np.all(v[at_corner] <= min(allowed, speed) + 2 * a * dt + 1e-9)


def test_a_mission_too_long_to_check_is_refused_before_the_work(tmp_path):
    scenario = write_world(tmp_path, width_m=30.0, height_m=20.0)  # no origin: a local frame
    line = tmp_path / "far.geojson"  # 10 degrees of latitude at 1.5 m/s: weeks of driving
    line.write_text(json.dumps({"type": "LineString",
                                "coordinates": [[11.5, 40.0], [11.5, 50.0]]}))
    code, _, err = run_cli("check", line, "--scenario", scenario)
    assert code == 2 and "samples" in err and len(err.strip().splitlines()) == 1
    many = tmp_path / "many.csv"
    many.write_text("x_m,y_m\n" + "".join(f"{i % 20},{i % 10}\n" for i in range(10_002)))
    code, _, err = run_cli("check", many, "--scenario", scenario)
    assert code == 2 and "10,002 rows, more than the 10,000" in err


def test_a_leg_through_an_obstacle_is_warned_about(ground, tmp_path):
    _, scenario, _, _ = ground
    path = tmp_path / "through.csv"
    path.write_text("x_m,y_m\n2,2\n28,8\n")  # the obstacle spans x 12..16, y 4..12
    code, text, err = run_cli("check", path, "--scenario", scenario, "--json")
    assert code == 0, err
    assert json.loads(text)["warnings"] == [
        "2 leg(s) leave the map's free space (an obstacle, a no-go zone or the boundary, "
        "within the robot's keep-away): leg 0 -> 1, return 1 -> 0"]
    assert "warning: 2 leg(s) leave" in err


def test_a_space_separated_wpl_file_with_a_delay_condition(aerial, tmp_path):
    """Some tools write QGC WPL 110 with spaces, not tabs; a CONDITION_DELAY (112) only
    delays the next DO command and moves nothing."""
    _, _, ctx, _ = aerial
    lat, lon = latlon(2, 2)
    far = latlon(25, 20)
    text = ("QGC WPL 110\n"
            f"0 1 0 16 0 0 0 0 {lat!r} {lon!r} {MUNICH.alt_m} 1\n"
            f"1 0 3 22 0 0 0 0 {lat!r} {lon!r} 12 1\n"
            "2 0 2 112 3 0 0 0 0 0 0 1\n"
            f"3 0 3 16 2.5 0 0 0 {far[0]!r} {far[1]!r} 12 1\n"
            "4 0 2 20 0 0 0 0 0 0 0 1\n")
    path = tmp_path / "spaces.txt"
    path.write_text(text)
    mission = read_mission(path, ctx.world.map.origin)
    assert mission.takeoff_alt_m == 12 and mission.returns_home
    assert mission.waypoints[1].stay_s == 2.5
    assert (mission.waypoints[1].x_m, mission.waypoints[1].y_m) == pytest.approx((25, 20),
                                                                                 abs=1e-6)
