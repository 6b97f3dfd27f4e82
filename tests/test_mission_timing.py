"""Timing of ``planning.mission_check`` on survey-like routes: corner arcs, hairpins, the
landing speed, and the motion samples that price a mission under many models."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from conftest import REPO

from orange_plan.context import context_of
from orange_plan.errors import InputError
from orange_plan.export.missions_in import Mission, MissionWaypoint
from orange_plan.planning.mission_check import check_mission, mission_samples
from orange_plan.scenario import load_scenario

ALT_M = 20.0
SPEED_MPS = 4.0


@pytest.fixture(scope="module")
def drone():
    """The shipped DJI M100 scenario (aerial, accel 2 m/s^2, climb 2.2, landing 1 m/s)."""
    return load_scenario(REPO / "scenarios" / "dji_m100.toml")


def mission(points, radius=None) -> Mission:
    """Home at the origin, then ``points`` (x, y) at ALT_M, every leg at SPEED_MPS."""
    wps = [MissionWaypoint(0.0, 0.0, 0.0, speed_mps=SPEED_MPS)]
    wps += [MissionWaypoint(x, y, ALT_M, speed_mps=SPEED_MPS, corner_radius_m=radius)
            for x, y in points]
    return Mission(tuple(wps), returns_home=False)


def flown_m(m: Mission, scenario) -> float:
    """Distance flown along the samples (speed x time) [m]."""
    state, weight = mission_samples(m, scenario, in_map_frame=False)
    return float(np.sum(np.asarray(state.speed_mps) * weight))


def test_a_corner_is_flown_on_its_arc(drone):
    # 40 m legs turning 90 degrees on a 20 m radius: the arc (pi/2 x 20 = 31.4 m) replaces
    # 2 x 20 m of polyline, 8.6 m less; the straight version of the same length is the check
    straight = mission([(0.0, 1.0), (0.0, 41.0), (0.0, 81.0)], radius=20.0)
    corner = mission([(0.0, 1.0), (0.0, 41.0), (40.0, 41.0)], radius=20.0)
    saving = 2 * 20.0 - math.pi / 2 * 20.0
    assert flown_m(straight, drone) - flown_m(corner, drone) == pytest.approx(saving, abs=0.3)


def test_a_hairpin_is_a_stop_not_a_crawl(drone):
    # a 179.9-degree reversal on a 20 m radius: the velocity must pass through zero, so the
    # reversal takes at least the time of stopping there (the arc's speed would be 0.19 m/s)
    hairpin = mission([(0.0, 1.0), (0.0, 101.0), (0.17, 1.0)], radius=20.0)
    wps = list(hairpin.waypoints)
    wps[2] = replace(wps[2], corner_radius_m=None)  # the same route, stopping at the reversal
    stop = replace(hairpin, waypoints=tuple(wps))
    t_hairpin = check_mission(hairpin, drone, in_map_frame=False).duration_s
    t_stop = check_mission(stop, drone, in_map_frame=False).duration_s
    assert t_hairpin == pytest.approx(t_stop, rel=0.02)


@pytest.mark.parametrize("landing_mps", [1.0, 0.5])
def test_the_landing_descends_at_the_landing_speed(drone, landing_mps):
    scenario = replace(drone, robot=replace(drone.robot, landing_mps=landing_mps))
    legs = check_mission(mission([(0.0, 50.0)]), scenario, in_map_frame=False).legs
    assert legs[-1].kind == "landing"
    # 20 m at the landing speed, plus the ramps at 2 m/s^2 (under 1 s)
    assert ALT_M / landing_mps <= legs[-1].duration_s <= ALT_M / landing_mps + 1.0


def test_without_a_landing_speed_the_landing_uses_the_descent_speed(drone):
    scenario = replace(drone, robot=replace(drone.robot, landing_mps=None))
    legs = check_mission(mission([(0.0, 50.0)]), scenario, in_map_frame=False).legs
    v, a = drone.robot.descent_mps, drone.robot.accel_max_mps2
    assert legs[-1].duration_s == pytest.approx(ALT_M / v + v / a, abs=0.3)  # with its ramps


def test_a_landing_speed_must_be_positive(tmp_path):
    from conftest import write_scenario

    with pytest.raises(InputError, match="landing_mps"):
        load_scenario(write_scenario(tmp_path, {"robot.landing_mps": 0.0}))


def test_mission_samples_price_the_check(drone):
    m = mission([(0.0, 1.0), (0.0, 41.0), (40.0, 41.0), (40.0, 200.0)], radius=20.0)
    ctx = context_of(drone)
    state, weight = mission_samples(m, ctx, in_map_frame=False)
    energy = float(np.asarray(ctx.model.power_W(state), float) @ weight)
    checked = check_mission(m, ctx, in_map_frame=False)
    assert energy == pytest.approx(checked.energy_J, rel=1e-9)
    assert weight.sum() == pytest.approx(checked.duration_s, rel=1e-9)
