"""Pieces of the tour planner: BIT* refinement, speeds, the distance baseline, the bound."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from planning_worlds import write_world

from orange_plan.context import load_context
from orange_plan.errors import InputError
from orange_plan.physics.conditions import Conditions
from orange_plan.physics.pathcost import path_energy
from orange_plan.planning import orienteering
from orange_plan.planning.plan import StartState
from orange_plan.planning.tour import (
    distance_context,
    min_energy_per_m,
    plan_tour,
    refine_legs,
    sensing_speed_mps,
    tour_setup,
    tour_speed_mps,
    walk_vertices,
)


@pytest.fixture
def hilly(tmp_path):
    return load_context(write_world(tmp_path, width_m=60, height_m=40, hill=(30, 20, 6, 8),
                                    obstacles=[(20, 5, 24, 30)], rated_energy_Wh=2.0))


def test_bitstar_refinement_only_keeps_cheaper_legs(hilly):
    # A 40-vertex roadmap leaves room for BIT* to find cheaper legs.
    setup = tour_setup(hilly, StartState(), 40, 3, 60, lambda s: None)
    tour = orienteering.solve(replace(setup.problem,
                                      budget_J=0.5 * setup.reach.energy_available_J))
    ex = setup.reach.exact

    def energy(s, ids):
        return path_energy(ex.model, ex.world, s.roadmap_xy_m[ids], ex.speed_mps,
                           ex.conditions, accel_max_mps2=ex.accel_max_mps2).total_J

    before = energy(setup, walk_vertices(setup, tour.nodes))
    refined, ids, n = refine_legs(setup, tour.nodes, seconds=0.5, max_legs=3, seed=1)
    after = energy(refined, ids)
    assert n >= 1 and after < before
    xy = refined.roadmap_xy_m[ids]
    assert hilly.world.segments_free(xy[:-1], xy[1:]).all()
    assert np.isfinite(refined.to_home.energy_J[ids]).all()
    # Off: the walk is the roadmap's.
    same, ids0, n0 = refine_legs(setup, tour.nodes, seconds=0.0)
    assert n0 == 0 and same is setup
    assert np.array_equal(ids0, walk_vertices(setup, tour.nodes))


def test_sensing_speed_is_one_frame_per_footprint_radius(tmp_path):
    ctx = load_context(write_world(tmp_path))
    sc = ctx.scenario
    # planning_worlds: sensor_rate_Hz = 0 -> no cap below v_max
    assert sensing_speed_mps(ctx) == sc.robot.v_max_mps
    anc = replace(sc.ancillary, sensor_rate_Hz=1.2)
    slow = ctx.with_scenario(replace(sc, ancillary=anc))
    assert sensing_speed_mps(slow) == pytest.approx(1.0 * 1.2)  # r = 1 m, 1.2 Hz


def test_tour_speed_balances_energy_and_time(tmp_path):
    ctx = load_context(write_world(tmp_path, rated_energy_Wh=50.0))
    assert tour_speed_mps(ctx, StartState()) == pytest.approx(ctx.cruise_speed_mps)
    mission = replace(ctx.scenario.mission, time_limit_s=60.0)
    timed = ctx.with_scenario(replace(ctx.scenario, mission=mission))
    # 50 Wh in 60 s: energy is no limit, so the fastest speed drives farthest.
    assert tour_speed_mps(timed, StartState()) == pytest.approx(ctx.scenario.robot.v_max_mps)


def test_distance_context_is_flat_and_windless(hilly):
    flat = distance_context(hilly)
    assert flat.world.map.elevation is None and flat.world.map.surfaces == ()
    assert flat.conditions.wind_xy_mps == (0.0, 0.0)
    # Energy per metre is then the same in every direction and place.
    e = [path_energy(flat.model, flat.world, np.array([[a, b], [a + 5, b]]), 1.0,
                     Conditions(0.9)).total_J
         for a, b in [(2, 2), (40, 30)]]
    assert e[0] == pytest.approx(e[1])


def test_min_energy_per_m_is_eq6_denominator_on_the_cheapest_ground(hilly):
    sc = hilly.scenario
    e = min_energy_per_m(hilly)
    d_max = sc.battery.usable_J / e
    # rated 2 Wh, the yard's cheapest ground is the default 0.03 (no surfaces here)
    from orange_plan.physics.range import simplified_range

    assert d_max == pytest.approx(simplified_range(sc, hilly.model, 0.03).d_max_m)


def test_time_limit_already_spent_is_refused(hilly):
    mission = replace(hilly.scenario.mission, time_limit_s=100.0)
    timed = hilly.with_scenario(replace(hilly.scenario, mission=mission))
    with pytest.raises(InputError, match="already spent"):
        plan_tour(timed, StartState(time_s=150.0), n_vertices=100)


def test_time_limit_is_kept(hilly):
    mission = replace(hilly.scenario.mission, time_limit_s=120.0)
    timed = hilly.with_scenario(replace(hilly.scenario, mission=mission))
    plan = plan_tour(timed, n_vertices=250, bitstar_s=0)
    assert plan.t_s[-1] <= 120.0 * (1 + 1e-6)
    free = plan_tour(hilly, n_vertices=250, bitstar_s=0)
    assert free.summary["coverage_m2"] >= plan.summary["coverage_m2"]


def test_warm_replan_reuses_the_roadmap_and_keeps_every_margin(hilly):
    from orange_plan.planning.tour import TourPlanner

    planner = TourPlanner(hilly, n_vertices=250, bitstar_legs=0)
    first = planner.plan()
    roadmap = planner.setup.roadmap
    mid = len(first.xy_m) // 3
    start = StartState(tuple(first.xy_m[mid]), float(first.energy_used_J[mid]),
                       float(first.t_s[mid]), first.covered)
    heavier = hilly.model.with_theta({n: 1.3 * v for n, v in hilly.model.as_dict().items()})
    again = planner.plan(start, model=heavier)
    assert planner.setup.roadmap is roadmap  # warm: the first plan's roadmap is kept
    assert np.allclose(again.xy_m[0], start.xy_m)
    assert np.allclose(again.xy_m[-1], hilly.world.home_xy_m)
    assert np.all(again.margin_J >= 0)
    assert hilly.world.segments_free(again.xy_m[:-1], again.xy_m[1:]).all()
    # Its energies are the heavier model's, as a cold plan's would be.
    sc = hilly.scenario
    exact = path_energy(heavier, hilly.world, again.xy_m, again.speed_mps[:-1], hilly.conditions,
                        accel_max_mps2=sc.robot.accel_max_mps2)
    assert again.energy_used_J[-1] - again.energy_used_J[0] == pytest.approx(exact.total_J,
                                                                             rel=1e-9)
