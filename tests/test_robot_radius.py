"""The robot's size: every path keeps ``robot.radius_m + mission.clearance_m`` from the map.

The World plans in the map inflated by that keep-away (obstacles and no-go zones grown, the
boundary shrunk), so tours, lawnmower paths, reach answers and map updates all inherit it;
coverage is still counted on the map as given (the sensor sees up to the walls).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from conftest import run_cli, write_scenario
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from planning_worlds import draw_world_spec, write_world

from orange_plan.context import load_context
from orange_plan.errors import InputError, ScenarioError
from orange_plan.planning.coverage import coverage_grid, footprint
from orange_plan.planning.lawnmower import plan_lawnmower
from orange_plan.planning.reach import prepare_reach, query_goals
from orange_plan.planning.tour import plan_tour
from orange_plan.scenario import load_scenario

TOLERANCE_M = 1e-6


def clearance_m(world, xy) -> float:
    """Smallest distance from a polyline's segments to the map as given (boundary edges,
    obstacles, no-go zones) [m]."""
    xy = np.asarray(xy, float)
    pieces = (shapely.linestrings(np.stack([xy[:-1], xy[1:]], axis=1)) if len(xy) > 1
              else shapely.points(xy))
    m = world.true_map
    walls = shapely.union_all([m.boundary.boundary, *m.obstacles, *m.no_go])
    return float(shapely.distance(pieces, walls).min())


@st.composite
def sized_worlds(draw):
    spec = draw_world_spec(draw, width_cells=(12, 20), height_cells=(8, 14), box_cells=(3, 5),
                           hill_height_m=4.0, ramp_max=0.08, surface_width_m=8.0)
    return dict(spec, rated_energy_Wh=draw(st.floats(0.15, 1.0)),
                radius_m=draw(st.floats(0.05, 0.9)),
                clearance_m=draw(st.sampled_from([0.0, 0.1, 0.4])))


@pytest.mark.timeout(300)
@settings(max_examples=6, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(spec=sized_worlds(), seed=st.integers(0, 1000), goals=st.integers(0, 10_000))
def test_every_path_keeps_the_robot_radius_from_the_map(tmp_path_factory, spec, seed, goals):
    ctx = load_context(write_world(tmp_path_factory.mktemp("sized"), **spec))
    world = ctx.world
    keep = spec["radius_m"] + spec["clearance_m"]
    assert ctx.scenario.keep_away_m == pytest.approx(keep)

    try:
        plan = plan_tour(ctx, n_vertices=200, seed=seed, max_candidates=40, bitstar_s=0.05,
                         bitstar_legs=1)
    except InputError as exc:  # battery too small or home boxed in: said, not crashed
        event("tour refused")
        assert "too small" in str(exc) or "boxed in" in str(exc), exc
    else:
        assert clearance_m(world, plan.xy_m) >= keep - TOLERANCE_M

    reach = prepare_reach(ctx, n_vertices=200, seed=seed)
    mower = plan_lawnmower(ctx, reach=reach, angle_deg=0.0, n_vertices=200, seed=seed)
    assert clearance_m(world, mower.xy_m) >= keep - TOLERANCE_M

    rng = np.random.default_rng(goals)
    x0, y0, x1, y1 = world.true_map.boundary.bounds
    points = rng.uniform((x0, y0), (x1, y1), size=(6, 2))
    answered = [g for g in query_goals(reach, points) if g.path_xy_m is not None]
    event(f"{len(answered)} reach paths")
    for goal in answered:
        assert clearance_m(world, goal.path_xy_m) >= keep - TOLERANCE_M
    for goal in query_goals(reach, points):  # a goal nearer the walls than the robot fits
        if goal.valid:
            assert clearance_m(world, [[goal.x_m, goal.y_m]]) >= keep - TOLERANCE_M


def test_coverage_counts_the_map_as_given(tmp_path):
    """The grid and the footprint read the uninflated free space: a pass beside a wall senses
    the strip between the robot's edge and the wall."""
    radius = 0.8
    ctx = load_context(write_world(tmp_path, width_m=20.0, height_m=10.0, radius_m=radius,
                                   obstacles=[(8.0, 4.0, 12.0, 6.0)]))
    world = ctx.world
    true_free = world.true_map.free_space.area
    assert world.map.free_space.area < true_free - 10.0  # the planner's space is smaller
    grid = coverage_grid(world, 1.0)
    assert grid.free_area_m2 == pytest.approx(true_free)
    # A point on the edge of the planner's space, 0.8 m from the south wall and the sensor's
    # 1 m disc reaching the wall: the whole disc below it is sensed.
    seen = footprint(world, [(5.0, radius)], 1.0)
    assert seen.area > 0.5 * math.pi  # more than the half disc above the robot
    assert seen.bounds[1] == pytest.approx(0.0)


def test_a_zero_radius_plans_in_the_map_as_given(tmp_path):
    ctx = load_context(write_world(tmp_path))
    assert ctx.scenario.robot.radius_m == 0.0 and ctx.scenario.mission.clearance_m == 0.0
    assert ctx.world.map is ctx.world.true_map


@pytest.mark.parametrize(("key", "value", "match"), [
    ("robot.radius_m", -0.1, r"robot.radius_m = -0.1 must be >= 0"),
    ("robot.radius_m", math.nan, r"robot.radius_m must be finite, got nan"),
    ("robot.radius_m", math.inf, r"robot.radius_m must be finite"),
    ("mission.clearance_m", -1.0, r"mission.clearance_m = -1 must be >= 0"),
])
def test_bad_radius_is_refused_in_one_line(tmp_path, key, value, match):
    path = write_scenario(tmp_path, set={key: value})
    with pytest.raises(ScenarioError, match=match) as info:
        load_scenario(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_radius_and_clearance_are_read(tmp_path):
    sc = load_scenario(write_scenario(tmp_path, set={"robot.radius_m": 0.3,
                                                     "mission.clearance_m": 0.05}))
    assert sc.robot.radius_m == 0.3 and sc.mission.clearance_m == 0.05
    assert sc.keep_away_m == pytest.approx(0.35)


def test_a_radius_bigger_than_the_map_is_one_clear_line(tmp_path):
    path = write_scenario(tmp_path, set={"robot.radius_m": 6.0})  # the yard is 10 m wide
    code, out, err = run_cli("range", path)
    assert code == 2, (out, err)
    line = err.strip()
    assert "\n" not in line and "robot.radius_m + mission.clearance_m = 6 m leaves no room" in line


def test_home_closer_than_the_radius_names_the_distance(tmp_path):
    # The yard's home (2, 5) is 2 m from the west edge of the boundary.
    path = write_scenario(tmp_path, set={"robot.radius_m": 2.0, "mission.clearance_m": 0.5})
    with pytest.raises(ScenarioError, match=r"home at \(2, 5\) m is 2 m from the nearest "
                       r"obstacle, no-go zone or boundary edge.*= 2.5 m") as info:
        load_context(path)
    assert "\n" not in str(info.value)


def test_a_route_point_too_near_a_wall_names_the_distance(tmp_path):
    ctx = load_context(write_world(tmp_path, radius_m=0.5))
    with pytest.raises(InputError, match=r"waypoint 1 at \(10, 0.3\) m is 0.3 m from"):
        ctx.world.check_points([(5.0, 5.0), (10.0, 0.3)], "waypoint")


def test_a_reach_goal_too_near_a_wall_is_invalid_with_its_distance(tmp_path):
    ctx = load_context(write_world(tmp_path, radius_m=0.5))
    reach = prepare_reach(ctx, n_vertices=150, seed=0)
    near, clear = query_goals(reach, [(10.0, 0.3), (10.0, 5.0)])
    assert not near.valid and near.path_xy_m is None
    assert near.reason.startswith("0.3 m from the nearest obstacle, no-go zone or boundary edge")
    assert clear.valid
