"""planning.reach and planning.goals: goal answers, reserve rules, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from planning_worlds import write_world
from scipy.stats import norm

from orange_plan.context import load_context
from orange_plan.errors import InputError
from orange_plan.physics.pathcost import path_energy
from orange_plan.planning.goals import load_goals
from orange_plan.planning.paths import path_gradient
from orange_plan.planning.reach import (
    home_status,
    prepare_reach,
    query_goals,
    query_points,
    reserve_J,
)
from orange_plan.scenario import Reserve

pytestmark = pytest.mark.timeout(60)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    folder = tmp_path_factory.mktemp("reach")
    return load_context(write_world(folder, obstacles=[(10, 5, 14, 25)], hill=(28, 20, 4.0, 5.0),
                                    surfaces=[(20, 0, 40, 15, 0.1)], rated_energy_Wh=0.5,
                                    reserve={"confidence": 0.95}))


@pytest.fixture(scope="module")
def reach(world):
    return prepare_reach(world, n_vertices=300, seed=2)


def test_reserve_rules():
    var = np.array([0.0, 100.0])
    assert reserve_J(Reserve("fraction", 0.1), 5000.0, var).tolist() == [500.0, 500.0]
    assert reserve_J(Reserve("energy_J", 42.0), 5000.0, var).tolist() == [42.0, 42.0]
    z = norm.ppf(0.99)
    assert reserve_J(Reserve("confidence", 0.99), 5000.0, var) == pytest.approx([0.0, 10 * z])


def test_goal_answers_are_exact_round_trips(world, reach):
    goals = query_goals(reach, [[35.0, 25.0], [38.0, 3.0]], ["a", "b"])
    c = reach.exact
    for g in goals:
        assert g.valid and g.name in "ab"
        e = path_energy(world.model, world.world, g.path_xy_m, c.speed_mps, c.conditions,
                        c.accel_max_mps2)
        assert g.energy_to_goal_J + g.energy_goal_to_home_J == pytest.approx(e.total_J, rel=1e-12)
        assert g.reserve_J > 0  # confidence reserve from the model's parameter variance
        assert g.margin_J == pytest.approx(reach.energy_available_J - e.total_J - g.reserve_J)
        assert g.feasible == (g.margin_J >= 0)
        assert np.allclose(g.path_xy_m[[0, -1]], world.world.home_xy_m)


def test_confidence_reserve_is_sized_from_the_predictive_variance(world, reach):
    # z_p sqrt(g' Cov g + (discrepancy_rel_sd E)^2): parameters and run-to-run spread
    model, z = world.model, norm.ppf(0.95)
    for g in query_goals(reach, [[35.0, 25.0], [38.0, 3.0]]):
        energy = g.energy_to_goal_J + g.energy_goal_to_home_J
        param = float(model.energy_variance_J2(path_gradient(reach.exact, g.path_xy_m)))
        assert g.reserve_J == pytest.approx(z * np.sqrt(param + (model.discrepancy_rel_sd
                                                                 * energy) ** 2))
        assert g.reserve_J > z * model.discrepancy_rel_sd * energy > 0
    pts = query_points(reach, [[35.0, 25.0]])
    assert pts.reserve_J[0] > z * model.discrepancy_rel_sd * (pts.energy_to_goal_J[0]
                                                              + pts.energy_goal_to_home_J[0])


def test_invalid_goals_have_reasons(reach):
    inside, outside = query_goals(reach, [[12.0, 10.0], [50.0, 10.0]])
    assert not inside.valid and not inside.feasible and "obstacle" in inside.reason
    assert not outside.valid and "outside the boundary" in outside.reason
    assert "margin_J" in inside.to_dict() and "name" not in inside.to_dict()


def test_energy_used_makes_goals_infeasible(world):
    full = world.scenario.battery.usable_J
    r = prepare_reach(world, start_xy=(30.0, 5.0), energy_used_J=full - 50.0, n_vertices=200)
    (g,) = query_goals(r, [[35.0, 25.0]])
    assert g.valid and not g.feasible and g.margin_J < 0 and "exceed" in g.reason
    home = home_status(r)
    assert not home.reachable and home.energy_to_home_J > 0


def test_goal_at_home_costs_nothing(world, reach):
    (g,) = query_goals(reach, [world.world.home_xy_m])
    assert g.feasible and g.energy_to_goal_J == 0.0 == g.energy_goal_to_home_J


def test_home_unreachable_behind_a_wall(tmp_path):
    ctx = load_context(write_world(tmp_path, obstacles=[(18, 0, 22, 30)]))
    r = prepare_reach(ctx, start_xy=(30.0, 15.0), n_vertices=150)
    assert not home_status(r).reachable and home_status(r).energy_to_home_J is None
    (g,) = query_goals(r, [[35.0, 10.0]])
    assert g.valid and not g.feasible and "unreachable" in g.reason


def test_fast_points_agree_with_exact_goals(reach):
    pts = np.array([[35.0, 25.0], [38.0, 3.0], [25.0, 28.0]])
    fast = query_points(reach, pts)
    exact = query_goals(reach, pts)
    for i, g in enumerate(exact):
        total = g.energy_to_goal_J + g.energy_goal_to_home_J
        assert fast.energy_to_goal_J[i] + fast.energy_goal_to_home_J[i] == pytest.approx(
            total, rel=0.05)
    assert query_points(reach, [[12.0, 10.0]]).feasible.tolist() == [False]


def test_bad_start_and_energy(world):
    with pytest.raises(InputError, match=r"^start_xy "):  # the Python API names its argument
        prepare_reach(world, start_xy=(12.0, 10.0), n_vertices=50)
    with pytest.raises(InputError, match=r"^energy_used_J = "):
        prepare_reach(world, energy_used_J=-1.0, n_vertices=50)


def test_load_goals(tmp_path):
    f = tmp_path / "g.csv"
    f.write_text("name,x_m,y_m,extra\nA,1,2,z\nB,3.5,-4,\n", encoding="utf-8")
    goals = load_goals(f)
    assert goals.xy_m.tolist() == [[1.0, 2.0], [3.5, -4.0]] and goals.names == ("A", "B")
    f.write_text("x_m,y_m\n1,2\n", encoding="utf-8")
    assert load_goals(f).names == (None,)


@pytest.mark.parametrize("text, match", [
    ("x,y\n1,2\n", "missing column"),
    ("x_m,y_m\n", "no goals"),
    ("x_m,y_m\n1,abc\n", "row 2: y_m = 'abc' is not a number"),
    ("x_m,y_m\n1,nan\n", "not finite"),
])
def test_bad_goals(tmp_path, text, match):
    f = tmp_path / "g.csv"
    f.write_text(text, encoding="utf-8")
    with pytest.raises(InputError, match=match):
        load_goals(f)
    with pytest.raises(InputError, match="not found"):
        load_goals(tmp_path / "none.csv")


def test_time_limit_makes_far_goals_infeasible_with_the_reason(tmp_path):
    ctx = load_context(write_world(tmp_path, obstacles=[(10, 5, 14, 25)], time_limit_s=40.0))
    r = prepare_reach(ctx, n_vertices=200, seed=2)
    near, far = query_goals(r, [[6.0, 3.0], [35.0, 25.0]])
    assert near.feasible and near.reason is None and near.duration_s <= 40.0
    assert far.margin_J > 0  # the energy would do ...
    assert not far.feasible and far.duration_s > 40.0  # ... the time does not
    assert far.reason == f"mission time {far.duration_s:,.0f} s exceeds mission.time_limit_s = 40 s"
    c = r.exact
    trip = path_energy(ctx.model, ctx.world, far.path_xy_m, c.speed_mps, c.conditions,
                       c.accel_max_mps2)
    assert far.duration_s == pytest.approx(trip.duration_s)
    # time already spent counts against the limit too
    later = prepare_reach(ctx, n_vertices=200, seed=2, time_used_s=40.0 - near.duration_s + 1.0)
    (again,) = query_goals(later, [[6.0, 3.0]])
    assert not again.feasible and "exceeds mission.time_limit_s" in again.reason
