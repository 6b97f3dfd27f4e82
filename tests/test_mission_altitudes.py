"""``check`` and the altitude frames of the QGroundControl plan format: above home
(``MAV_FRAME_GLOBAL_RELATIVE_ALT``, 3), above mean sea level (``MAV_FRAME_GLOBAL``, 0) and
above the terrain (``MAV_FRAME_GLOBAL_TERRAIN_ALT``, 10). A survey flown from a ridge has its
waypoints below home: that is fine above the ground, and only a waypoint below the ground is
refused."""

from __future__ import annotations

import json
import math

import pytest
from conftest import run_cli
from hypothesis import given, settings
from hypothesis import strategies as st
from planning_worlds import write_world
from test_export import MUNICH, with_origin
from test_mission_check import latlon, make_aerial, qgc_file, qgc_item

from orange_plan.context import load_context
from orange_plan.errors import InputError
from orange_plan.export.missions_in import Mission, MissionWaypoint, read_mission
from orange_plan.planning.mission_check import check_mission

SLOPE = -1.0
"""The valley's ground falls 1 m per metre east of home (x = 2 m)."""
SITE = (40.0, 10.0)
"""The surveyed point: its ground lies 38 m below home."""
GROUND_AT_SITE_M = SLOPE * (SITE[0] - 2.0)


@pytest.fixture(scope="module")
def valley(tmp_path_factory):
    folder = tmp_path_factory.mktemp("valley")
    scenario = make_aerial(with_origin(write_world(folder, width_m=60.0, height_m=40.0,
                                                   ramp=SLOPE, rated_energy_Wh=2.0)))
    return folder, scenario, load_context(scenario)


def survey_plan(folder, frame: int, alt: float):
    """Take off to 10 m, fly to the site at ``alt`` in ``frame``, return home."""
    items = [qgc_item(22, [0, 0, 0, None, *latlon(2, 2), 10]),
             qgc_item(16, [0, 0, 0, None, *latlon(*SITE), alt], frame=frame),
             qgc_item(20, [0, 0, 0, 0, 0, 0, 0], frame=2)]
    path = folder / f"survey_{frame}_{alt:g}.plan"
    path.write_text(json.dumps(qgc_file(items)))
    return path


# frame, altitude in that frame, altitude above home it means
ABOVE_THE_GROUND = [(3, -20.0, -20.0), (6, -20.0, -20.0), (0, MUNICH.alt_m - 20.0, -20.0),
                    (5, MUNICH.alt_m - 20.0, -20.0), (10, 5.0, GROUND_AT_SITE_M + 5.0),
                    (11, 5.0, GROUND_AT_SITE_M + 5.0)]


@pytest.mark.parametrize("frame, alt, above_home", ABOVE_THE_GROUND)
def test_a_waypoint_below_home_above_the_ground_is_checked(valley, frame, alt, above_home):
    folder, scenario, ctx = valley
    path = survey_plan(folder, frame, alt)
    result = check_mission(read_mission(path, ctx.world.map.origin), ctx)
    leg = next(leg for leg in result.legs if leg.kind == "leg")
    assert leg.to_xyz_m[2] == pytest.approx(above_home, abs=1e-6)
    assert leg.climb_m == pytest.approx(above_home - 10.0, abs=1e-6)
    code, out, err = run_cli("check", path, "--scenario", scenario, "--json")
    assert code == 0, err
    assert json.loads(out)["legs"][1]["to_xyz_m"][2] == pytest.approx(above_home, abs=1e-6)


BELOW_THE_GROUND = [(3, -45.0, "below the ground there"),
                    (0, MUNICH.alt_m - 45.0, "below the ground there"),
                    (10, -1.0, "above the terrain is below the ground")]


@pytest.mark.parametrize("frame, alt, message", BELOW_THE_GROUND)
def test_a_waypoint_below_the_ground_is_refused_in_every_frame(valley, frame, alt, message):
    folder, scenario, _ = valley
    code, _, err = run_cli("check", survey_plan(folder, frame, alt), "--scenario", scenario)
    assert code == 2 and message in err
    assert len(err.strip().splitlines()) == 1, err


def test_on_flat_ground_a_waypoint_below_home_is_below_the_ground(tmp_path):
    scenario = make_aerial(with_origin(write_world(tmp_path, width_m=60.0, height_m=40.0)))
    route = tmp_path / "route.csv"
    route.write_text("x_m,y_m,z_m\n2,2,0\n20,5,-1\n")
    code, _, err = run_cli("check", route, "--scenario", scenario)
    assert code == 2 and "below the ground there (0 m above home)" in err


def test_the_way_home_from_below_home_climbs_to_homes_height_first(valley):
    """From below home the way home climbs on the spot to home's height, then flies home at
    it: it can never pass under its own take-off point (into the ridge)."""
    from orange_plan.planning.mission_stages import robot_limits, way_home

    _, _, ctx = valley
    robot = robot_limits(ctx)
    way = way_home((*SITE, -20.0), (2.0, 2.0), 1, None, robot)
    assert [st.kind for st in way] == ["return", "return"]
    assert way[0].vertical and way[0].end[2] == pytest.approx(0.0)
    assert way[1].start[2] == way[1].end[2] == pytest.approx(0.0)
    above = way_home((*SITE, 20.0), (2.0, 2.0), 1, None, robot)
    assert [st.kind for st in above] == ["return", "landing"]


def test_the_way_home_from_below_home_costs_the_climb(valley):
    _, _, ctx = valley
    low, high = (Mission((MissionWaypoint(2, 2), MissionWaypoint(*SITE, z)), 10.0, True)
                 for z in (-30.0, -10.0))
    home_low, home_high = (next(leg for leg in check_mission(m, ctx).legs
                                if leg.kind == "leg").energy_to_home_J for m in (low, high))
    assert home_low > home_high  # 20 m more to climb


def test_without_an_origin_a_waypoint_below_home_is_said_not_refused(valley):
    """In a local frame (a map without origin) the terrain is unknown: the check runs and says
    which waypoints nothing checked against the ground."""
    _, _, ctx = valley
    mission = Mission((MissionWaypoint(0, 0), MissionWaypoint(30, 0, -40.0)), 10.0, False)
    result = check_mission(mission, ctx, in_map_frame=False)
    assert any("1 waypoint(s) below home" in w for w in result.warnings)
    with pytest.raises(InputError, match="below the ground"):
        check_mission(mission, ctx)  # on the map: 40 m below home is under the valley floor


def test_a_terrain_relative_mission_follows_the_ground():
    """``Mission.above_home`` adds the ground's height where the waypoint is terrain-relative
    and leaves above-home altitudes alone."""
    mission = Mission((MissionWaypoint(0, 0), MissionWaypoint(10, 0, 5.0, above_terrain=True),
                       MissionWaypoint(20, 0, 5.0)))
    placed = mission.above_home(lambda x, y: -x)
    assert [w.z_m for w in placed.waypoints] == [0.0, -5.0, 5.0]
    assert not any(w.above_terrain for w in placed.waypoints)


def test_a_leg_through_a_ridge_between_two_waypoints_is_warned_about(tmp_path):
    """Both ends of the leg are above the ground; the hill between them is not under it: the
    check says which legs cut through the terrain (the waypoints alone cannot tell)."""
    scenario = make_aerial(with_origin(write_world(tmp_path, width_m=60.0, height_m=20.0,
                                                   hill=(30.0, 10.0, 30.0, 4.0),
                                                   rated_energy_Wh=2.0)))
    ctx = load_context(scenario)
    over = Mission((MissionWaypoint(2, 10), MissionWaypoint(55, 10, 40.0)), 40.0, True)
    through = Mission((MissionWaypoint(2, 10), MissionWaypoint(55, 10, 10.0)), 10.0, True)
    assert not check_mission(over, ctx).warnings
    warned = check_mission(through, ctx).warnings
    assert len(warned) == 1 and "2 leg(s) pass below the map's ground" in warned[0]
    assert "leg 0 -> 1" in warned[0] and "return 1 -> 0" in warned[0]


@settings(max_examples=200, deadline=None)
@given(x=st.floats(-500.0, 500.0), y=st.floats(-500.0, 500.0), z=st.floats(-300.0, 300.0),
       aerial=st.booleans())
def test_the_way_home_is_continuous_ends_home_and_never_sinks(x, y, z, aerial):
    """From anywhere, the way home is a chain of stages from there to home on the ground (an
    aerial robot's) that never goes lower than where it started or home's height, whichever
    is lower, and climbs only on the spot."""
    from orange_plan.planning.mission_stages import RobotLimits, way_home

    robot = RobotLimits(aerial, 3.0, 2.5, 1.5, 5.0, 2.0, 1.0)
    here = (x, y, z if aerial else 0.0)
    way = way_home(here, (0.0, 0.0), 3, None, robot)
    at = here
    for stage in way:
        assert stage.start == at
        assert min(stage.start[2], stage.end[2]) >= min(here[2], 0.0) - 1e-9
        if stage.end[2] > stage.start[2]:
            assert stage.vertical
        at = stage.end
    assert math.hypot(at[0], at[1]) <= 1e-3  # AT_HOME_M
    assert at[2] == pytest.approx(0.0, abs=1e-9)
