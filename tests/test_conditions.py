"""One Conditions value (duty cycle, sensor rate, wind) from the scenario to every consumer."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from planning_worlds import write_world

from orange_plan.context import load_context
from orange_plan.errors import InputError, OrangeError
from orange_plan.physics.conditions import Conditions
from orange_plan.physics.pathcost import path_energy, segments_energy
from orange_plan.physics.state import MotionState
from orange_plan.planning.reach import cost_contexts
from orange_plan.planning.speed import SpeedSolver, cut_path, speed_problem
from orange_plan.sim.route import Route
from orange_plan.sim.simulator import simulate
from orange_plan.world.rasters import build_rasters

PATH_XY_M = np.array([[2.0, 2.0], [30.0, 2.0], [30.0, 20.0]])


@pytest.fixture(scope="module")
def flat(tmp_path_factory):
    return load_context(write_world(tmp_path_factory.mktemp("flat")))


def test_context_conditions_are_the_scenarios(tmp_path):
    ctx = load_context(write_world(tmp_path, wind=(2.0, 90.0)))  # from the east: blows west
    sc = ctx.scenario
    assert ctx.conditions == Conditions(sc.mission.duty_cycle, sc.ancillary.sensor_rate_Hz,
                                        sc.environment.wind_xy_mps, sc.environment.ambient_C)
    np.testing.assert_allclose(ctx.conditions.wind_xy_mps, (-2.0, 0.0), atol=1e-12)


def test_a_wind_changed_once_reaches_path_costs_roadmap_speeds_and_the_simulator(flat):
    windy = replace(flat, conditions=flat.conditions.with_wind((1.5, 0.5)))
    speed = flat.cruise_speed_mps

    def path_J(ctx):
        return path_energy(ctx.model, ctx.world, PATH_XY_M, speed, ctx.conditions).total_J

    def edge_J(ctx):
        fast, _ = cost_contexts(ctx, build_rasters(ctx.world), speed)
        e_fwd, e_rev, _, _ = fast.costs(PATH_XY_M[:1], PATH_XY_M[1:2])
        return float(e_fwd[0]), float(e_rev[0])

    def speeds_J(ctx):
        problem = speed_problem(ctx, cut_path(ctx.world, PATH_XY_M, 4))
        assert problem.conditions is ctx.conditions
        return SpeedSolver(ctx.model).solve(problem).energy_J

    def sim_J(ctx):
        return simulate(ctx, Route(PATH_XY_M, np.full(len(PATH_XY_M), speed), "test")).energy_J

    for measure in (path_J, edge_J, speeds_J, sim_J):
        assert measure(windy) != measure(flat), measure.__name__
    # a tail wind along +x makes the first (eastward) edge cheaper, the way back dearer
    (calm_fwd, calm_rev), (wind_fwd, wind_rev) = edge_J(flat), edge_J(windy)
    assert wind_fwd < calm_fwd and wind_rev > calm_rev


@pytest.mark.parametrize("wind", [(0.0, 0.0), (1.5, 0.5)])
def test_the_simulator_draws_what_the_path_cost_predicts_under_the_same_conditions(flat, wind):
    """No truth-only effects: the simulated energy is the driven profile's path energy."""
    ctx = replace(flat, conditions=flat.conditions.with_wind(wind))
    speed = ctx.cruise_speed_mps
    sim = simulate(ctx, Route(PATH_XY_M, np.full(len(PATH_XY_M), speed), "test"))
    predicted = path_energy(ctx.model, ctx.world, PATH_XY_M, speed, ctx.conditions,
                            ctx.scenario.robot.accel_max_mps2)
    assert sim.energy_J == pytest.approx(predicted.total_J, rel=1e-6)


@settings(max_examples=40, deadline=None)
@given(duty=st.floats(0.05, 1.0), rate_Hz=st.floats(0.0, 50.0),
       wind_x=st.floats(-5.0, 5.0), wind_y=st.floats(-5.0, 5.0),
       heading=st.floats(-math.pi, math.pi), length_m=st.floats(0.5, 20.0))
def test_segment_energy_under_conditions_matches_a_hand_built_state(flat, duty, rate_Hz, wind_x,
                                                                    wind_y, heading, length_m):
    """Reference: the model's segment energy (docs/guide/range.md, Eq. 4) of a MotionState built by hand from the
    same duty cycle, rate and wind on flat default ground (no map look-ups, no Steps)."""
    conditions = Conditions(duty, rate_Hz, (wind_x, wind_y))
    a = np.array([20.0, 15.0])
    b = a + length_m / 2 * np.array([math.cos(heading), math.sin(heading)])
    got = segments_energy(flat.model, flat.world, [a], [b], 0.8, conditions)
    dist = float(np.hypot(*(b - a)))
    state = MotionState(speed_mps=0.8, dir_x=(b - a)[0] / dist, dir_y=(b - a)[1] / dist,
                        wind_x_mps=wind_x, wind_y_mps=wind_y, crr=flat.world.default_crr,
                        sensor_rate_Hz=rate_Hz)
    want = flat.model.segment_energy(state, dist, duty)
    assert float(got.total_J[0]) == pytest.approx(float(want.total_J), rel=1e-9)
    assert float(got.mission_time_s[0]) == pytest.approx(float(want.mission_time_s), rel=1e-9)


@pytest.mark.parametrize(("args", "message"), [
    ((0.0,), r"duty_cycle must be in \(0, 1\], got 0.0"),
    ((1.5,), r"duty_cycle must be in \(0, 1\], got 1.5"),
    ((math.nan,), "duty_cycle must be in"),
    ((0.9, -1.0), "sensor_rate_Hz must be a finite value >= 0, got -1.0"),
    ((0.9, math.inf), "sensor_rate_Hz must be a finite value >= 0"),
    ((0.9, 0.0, (math.nan, 0.0)), "wind_xy_mps must be two finite numbers"),
    ((0.9, 0.0, (1.0, 2.0, 3.0)), "wind_xy_mps must be two finite numbers"),
    ((0.9, 0.0, (0.0, 0.0), 200.0), r"ambient_C must be in \[-90, 150\] degC, got 200.0"),
    ((0.9, 0.0, (0.0, 0.0), math.nan), "ambient_C must be in"),
])
def test_bad_conditions_are_refused_with_the_reason(args, message):
    with pytest.raises(InputError, match=message):
        Conditions(*args)
    with pytest.raises(InputError, match="wind_xy_mps"):
        Conditions(0.9).with_wind((math.inf, 0.0))


def test_a_stale_context_copy_is_refused_and_with_scenario_rebuilds(flat):
    mission = replace(flat.scenario.mission, duty_cycle=0.5)
    with pytest.raises(OrangeError, match="disagree with the scenario's duty cycle"):
        replace(flat, scenario=replace(flat.scenario, mission=mission))
    assert flat.with_scenario(replace(flat.scenario, mission=mission)).conditions.duty_cycle == 0.5


def test_the_ambient_temperature_reaches_planned_and_driven_states(flat):
    """A temperature-dependent term (HVAC on the ambient temperature, diagnosed) charges
    planned paths at the scenario's ambient temperature, as it charges a recording at its
    column: path energy and the driven profile agree on it."""
    from orange_plan.physics.model_builder import model_with_terms

    model = model_with_terms(flat, [*flat.model.term_ids, "hvac_ambient"]).with_theta(
        {"hvac_heat_W_per_K": 10.0})
    speed = flat.cruise_speed_mps

    def path_J(ambient_C):
        conditions = replace(flat.conditions, ambient_C=ambient_C)
        return path_energy(model, flat.world, PATH_XY_M, speed, conditions)

    warm, cold = path_J(20.0), path_J(5.0)
    # 15 K below the setpoint x 10 W/K = 150 W more over the mission time
    assert cold.total_J - warm.total_J == pytest.approx(150.0 * warm.cumulative_time_s[-1], rel=1e-9)
