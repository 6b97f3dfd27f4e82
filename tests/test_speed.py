"""planning.speed: the CasADi speed optimiser against hand-computed optima."""

from __future__ import annotations

import numpy as np
import pytest
from planning_worlds import write_world

from orange_plan.context import load_context
from orange_plan.errors import InputError, PlanningError
from orange_plan.physics.state import MotionState
from orange_plan.planning.speed import SpeedSolver, cut_path, speed_problem

pytestmark = pytest.mark.timeout(60)
STRAIGHT = np.array([[2.0, 15.0], [38.0, 15.0]])


@pytest.fixture(scope="module")
def ctx(tmp_path_factory):
    # Heavy drag: the energy-optimal cruise speed lies inside [v_min, v_max].
    return load_context(write_world(tmp_path_factory.mktemp("speed"), drag=2.0,
                                    hill=(20.0, 25.0, 3.0, 6.0)))


def v_star(ctx) -> float:
    """argmin_v P_anc/(v D) + (crr m g + c v^2)/Omega  ->  v^3 = P_anc Omega / (2 c D)."""
    sc = ctx.scenario
    p_anc = (2.0 + 2.0 + 1.0) / (1 - sc.losses.ancillary)
    return (p_anc * sc.omega / (2 * sc.robot.drag_coeff_kg_per_m * sc.mission.duty_cycle)) ** (1 / 3)


def test_flat_optimum_is_the_closed_form_speed(tmp_path):
    ctx = load_context(write_world(tmp_path, drag=2.0))
    pieces = cut_path(ctx.world, STRAIGHT, 20)
    prof = SpeedSolver(ctx.model).solve(speed_problem(ctx, pieces), ctx.world)
    assert 0.2 < v_star(ctx) < 1.5
    assert np.allclose(prof.speed_mps, v_star(ctx), rtol=1e-4)


def test_mx_objective_equals_numpy_model(tmp_path):
    """The solver's own objective (CasADi, the clip as an epigraph variable) equals the numpy
    model's energy at its optimum, on a hill in a crosswind with regeneration: descents where
    the clip and the recovered share decide the energy."""
    ctx = load_context(write_world(tmp_path, drag=2.0, hill=(20.0, 15.0, 6.0, 5.0),
                                   wind=(4.0, 300.0), terms=("regen",)))
    pieces = cut_path(ctx.world, [[2, 5], [20, 15], [38, 5], [20, 25], [2, 5]], 60)
    solver = SpeedSolver(ctx.model)
    prof = solver.solve(speed_problem(ctx, pieces))
    wind_x, wind_y = ctx.conditions.wind_xy_mps
    state = MotionState(speed_mps=prof.speed_mps, cos_t=pieces.cos_t, sin_t=pieces.sin_t,
                        dir_x=pieces.dir_x, dir_y=pieces.dir_y, crr=pieces.crr,
                        wind_x_mps=wind_x, wind_y_mps=wind_y)
    force = ctx.model.traction_force_N(state)
    assert (force < 0).sum() >= 5 and (force > 0).sum() >= 5  # the clip is active both ways
    e = ctx.model.segment_energy(state, pieces.length_m, ctx.conditions.duty_cycle)
    numpy_J = float(np.sum(e.ancillary_J + e.traversal_J))
    assert prof.pieces_energy_J == pytest.approx(numpy_J, rel=1e-12)
    assert prof.objective == pytest.approx(numpy_J, rel=1e-6)


def test_time_limit_binds_and_accel_limit_holds(ctx):
    pieces = cut_path(ctx.world, [[2, 5], [20, 28], [38, 5]], 60)
    solver = SpeedSolver(ctx.model)
    free = solver.solve(speed_problem(ctx, pieces), ctx.world)
    limited = solver.solve(speed_problem(ctx, pieces, time_limit_s=0.8 * free.duration_s),
                           ctx.world)
    # the limit holds for the driven profile (ramps, stops), and binds
    assert limited.duration_s <= 0.8 * free.duration_s
    assert limited.duration_s == pytest.approx(0.8 * free.duration_s, rel=0.01)
    assert limited.pieces_duration_s < limited.duration_s  # the NLP's limit was tightened
    assert limited.energy_J > free.energy_J
    v2 = limited.speed_mps ** 2
    assert np.all(np.abs(np.diff(v2)) <= 2 * 0.5 * pieces.length_m[:-1] + 1e-6)


def test_time_limit_the_driven_profile_cannot_keep_is_refused(ctx):
    """Just above the time at v_max without ramps or stops: the NLP meets it, the robot
    (from and to rest, stopping on its duty cycle) cannot, and the answer says so."""
    pieces = cut_path(ctx.world, STRAIGHT, 20)
    r = ctx.scenario.robot
    fastest_s = float(np.sum(pieces.length_m)) / (r.v_max_mps * ctx.conditions.duty_cycle)
    problem = speed_problem(ctx, pieces, time_limit_s=1.001 * fastest_s)
    with pytest.raises(PlanningError, match=r"mission time \d+ s exceeds mission.time_limit_s"):
        SpeedSolver(ctx.model).solve(problem, ctx.world)


def test_min_time_within_energy_budget(ctx):
    pieces = cut_path(ctx.world, STRAIGHT, 20)
    solver = SpeedSolver(ctx.model)
    best = solver.solve(speed_problem(ctx, pieces), ctx.world)
    budget = 1.05 * best.energy_J
    fast = solver.solve(speed_problem(ctx, pieces, objective="time", energy_budget_J=budget),
                        ctx.world)
    assert fast.duration_s < best.duration_s
    # the budget holds for the driven profile (ramps and stops draw more than the NLP's pieces)
    assert fast.energy_J <= budget
    assert fast.pieces_energy_J < fast.energy_J


def test_cut_path_keeps_corners_and_count(ctx):
    pieces = cut_path(ctx.world, [[2, 5], [20, 28], [38, 5]], 25)
    assert pieces.n == 25 and len(pieces.xy_m) == 26
    assert any(np.allclose(p, [20, 28]) for p in pieces.xy_m)


def test_bad_input(ctx):
    pieces = cut_path(ctx.world, STRAIGHT, 10)
    with pytest.raises(InputError, match="shorter than the path takes at v_max"):
        speed_problem(ctx, pieces, time_limit_s=1.0)
    with pytest.raises(InputError, match="objective"):
        speed_problem(ctx, pieces, objective="fun")
    with pytest.raises(InputError, match="fewer than"):
        cut_path(ctx.world, [[2, 5], [20, 28], [38, 5]], 1)
