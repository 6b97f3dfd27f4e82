"""bench.plan (``orange-plan bench plan``), sim.perturb and the generated maps: a quick run on a
tiny map with a stand-in planner (structure and bookkeeping, never the measured figures)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from planning_worlds import write_world

from orange_plan.bench.maps import large_scenario, random_scenario
from orange_plan.bench.plan import (
    BUDGET_SHARES,
    METHODS,
    PlanBenchResult,
    ScenarioSpec,
    coverage_bound_m2,
    flight_of,
    plan_table,
    run_plan_bench,
    scenario_specs,
)
from orange_plan.bench.px4_rtl import HomePaths, cut_path
from orange_plan.context import load_context
from orange_plan.errors import InputError
from orange_plan.planning.coverage import footprint
from orange_plan.planning.lawnmower import cumulative_energy_time, plan_lawnmower
from orange_plan.planning.plan import SUMMARY_KEYS, Plan
from orange_plan.planning.reach import prepare_reach
from orange_plan.sim.perturb import NONE, calibration_truths, truth_multipliers
from orange_plan.sim.route import Route
from orange_plan.sim.simulator import simulate

pytestmark = pytest.mark.timeout(60)

COLUMNS = ("scenario", "method", "coverage_m2", "coverage_of_bound", "energy_left_J",
           "planner_seconds", "strandings", "flights", "ratio_vs_lawnmower")


def standin_planner(ctx, start=None, *, cost="physics", n_vertices=300, seed=0, progress=None):
    """A stand-in for ``planning.tour.plan_tour``: the lawnmower cut where the planning energy
    plus the way home reaches 70 % (physics) or a distance budget of 70 % (distance) of the
    usable energy, then home. Enough to exercise the harness; not a planner."""
    reach = prepare_reach(ctx, n_vertices=n_vertices, seed=seed)
    lawn = plan_lawnmower(ctx, reach, angle_deg=0.0)
    home = HomePaths(reach)
    energy, _t = cumulative_energy_time(ctx, reach.fast, lawn.xy_m)
    usable = ctx.scenario.battery.usable_J
    if cost == "distance":
        energy = np.r_[0.0, np.cumsum(np.hypot(*np.diff(lawn.xy_m, axis=0).T))] * home.e_per_m
    back = home.length_m(lawn.xy_m) * home.e_per_m
    ok = np.flatnonzero(energy + back <= 0.7 * usable)
    k = int(ok[-1]) if ok.size else 0
    xy = np.vstack([lawn.xy_m[: k + 1], home.path(lawn.xy_m[k])[1:]]) if k else lawn.xy_m[[0, 0]]
    xy = np.vstack([xy, xy[-1:] + 0.0]) if len(xy) < 2 else xy
    e, tt = cumulative_energy_time(ctx, reach.fast, xy)
    covered = footprint(ctx.world, xy, ctx.scenario.mission.sensor_radius_m)
    n = len(xy)
    to_home = e[-1] - e
    summary = {k: 0.0 for k in SUMMARY_KEYS} | {
        "energy_available_J": usable, "energy_planned_J": float(e[-1]),
        "coverage_m2": covered.area, "coverage_bound_m2": coverage_bound_m2(ctx)}
    return Plan(xy, tt, np.full(n, reach.exact.speed_mps), e, to_home, np.zeros(n),
                np.clip(usable - e - to_home, 0, None), xy[:1], covered, summary)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bench_plan")
    path = write_world(folder, width_m=40, height_m=30, obstacles=[(18, 10, 22, 20)],
                       home=(2.0, 2.0), rated_energy_Wh=0.5, reserve={"confidence": 0.95},
                       name="tiny")
    return path


def test_quick_run_has_every_column_and_the_same_truths(tiny):
    result = run_plan_bench([ScenarioSpec("tiny", (tiny,))], standin_planner, seeds=2)
    rows = result.rows()
    assert [r["method"] for r in rows] == list(METHODS)
    for row in rows:
        assert set(COLUMNS) <= set(row)
        assert row["flights"] == 2 and row["error"] is None
        assert row["coverage_m2"] > 0 and 0 < row["coverage_of_bound"] <= 1.0 + 1e-9
        assert 0 <= row["strandings"] <= 2
    assert rows[0]["ratio_vs_lawnmower"] is None and rows[2]["ratio_vs_lawnmower"] > 0
    assert [f.seed for f in result.results[0].flights] == [0, 1]
    data = json.loads(json.dumps(result.to_dict()))
    assert data["complete"] and len(data["flights"]) == len(METHODS)
    for row in data["rows"]:  # coverage against budget: one point per share, never falling
        curve = np.asarray(row["budget_curve"], float)
        assert curve.shape == (len(BUDGET_SHARES), 2)
        assert np.all(np.diff(curve[:, 1]) >= -1e-9)

    table = plan_table(result)
    headers = [c.header for c in table.columns]
    for col in ("coverage m2", "cov/bound", "left kJ", "planner s", "stranded", "ratio"):
        assert any(col in h for h in headers), col


def test_lawnmower_flight_turns_home_and_returns(tiny):
    ctx = load_context(tiny)
    result = run_plan_bench([ScenarioSpec("tiny", (tiny,))], None, seeds=1,
                            methods=("lawnmower",))
    (flight,) = result.results[0].flights
    # 0.5 Wh does not cover the 40 m x 30 m yard: the rule must fire, and the robot get home
    assert flight.turned_home_s is not None and flight.turned_home_s > 0
    assert flight.coverage_m2 < ctx.world.map.free_space.area


def test_stranding_is_detected(tiny):
    ctx = load_context(tiny)
    lawn = plan_lawnmower(ctx, prepare_reach(ctx, n_vertices=300), angle_deg=0.0)
    xy = np.vstack([lawn.xy_m] * 3)  # three laps: far beyond the battery
    sim = simulate(ctx, Route(xy, np.full(len(xy), np.nan), "laps"))
    flight = flight_of(ctx, sim, 0, coverage_bound_m2(ctx))
    assert flight.stranded and flight.energy_left_J < 0
    # what was flown before the battery ran out counts, not the whole route
    assert flight.coverage_m2 <= ctx.world.map.free_space.area


def test_truths_within_the_covariance_and_the_run_to_run_discrepancy(tiny):
    from dataclasses import replace

    from orange_plan.sim.perturb import Discrepancy

    ctx = load_context(tiny)
    truths = calibration_truths(ctx, 400, seed=3, discrepancy=NONE)
    mult = np.array([list(truth_multipliers(ctx, t).values()) for t in truths])
    rel = np.sqrt(np.diag(ctx.model.cov)) / np.abs(ctx.model.theta)
    nonzero = ctx.model.theta != 0
    assert np.allclose(mult.mean(axis=0), 1.0, atol=0.03)
    assert np.allclose(mult.std(axis=0), rel[nonzero], rtol=0.2)
    assert (mult >= 0).all()
    again = calibration_truths(ctx, 2, seed=3, discrepancy=NONE)
    assert again[0] == truths[0]  # seeded
    assert truths[0].roughness_crr_std == 0
    # the run factor alone (no coefficient covariance): one common multiplier per truth
    exact = replace(ctx, model=ctx.model.with_theta({}, np.zeros_like(ctx.model.cov)))
    runs = calibration_truths(exact, 400, seed=4, discrepancy=Discrepancy(run_rel_sd=0.2))
    m = np.array([list(truth_multipliers(exact, t).values()) for t in runs])
    assert np.allclose(m, m[:, :1])
    assert m[:, 0].std() == pytest.approx(0.2, rel=0.15) and m.min() > 0
    default = calibration_truths(ctx, 1, seed=3)[0]
    assert default.roughness_crr_std > 0  # ground robot: crr roughness
    with pytest.raises(InputError, match="must be >= 1"):
        calibration_truths(ctx, 0)


def test_generated_maps_load_and_are_seeded(tmp_path):
    a = random_scenario(tmp_path / "a", 1)
    b = random_scenario(tmp_path / "b", 1)
    assert a.read_text() == b.read_text()
    assert (tmp_path / "a" / "random_1.geojson").read_text() == \
        (tmp_path / "b" / "random_1.geojson").read_text()
    ctx = load_context(a)
    assert ctx.world.map.obstacles
    specs = scenario_specs(["random"], tmp_path / "fam", family_size=2)
    assert [len(s.paths) for s in specs] == [2]
    with pytest.raises(InputError, match="no scenario 'nope'"):
        scenario_specs(["nope"], tmp_path)


def test_large_map_has_300_obstacles_and_a_dem(tmp_path):
    ctx = load_context(large_scenario(tmp_path))
    xmin, ymin, xmax, ymax = ctx.world.map.boundary.bounds
    assert (xmax - xmin, ymax - ymin) == (2000.0, 2000.0)
    assert len(ctx.world.map.obstacles) == 300
    assert ctx.world.map.elevation is not None


def test_cut_path_and_partial_result():
    xy = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    assert np.allclose(cut_path(xy, 15.0), [[0, 0], [10, 0], [10, 5]])
    assert np.allclose(cut_path(xy, 50.0), xy)
    empty = PlanBenchResult(2, [], complete=False)
    assert empty.to_dict()["rows"] == [] and not empty.to_dict()["complete"]


def test_cli_quick_json_with_a_standin_planner(tmp_path):
    from conftest import run_cli

    out = tmp_path / "bench.json"
    code, stdout, stderr = run_cli("bench", "plan", "--quick", "--seeds", "1", "--json",
                                   "--planner", "test_bench_plan:standin_planner",
                                   "--out", out, "--png", tmp_path / "fig.png")
    assert code == 0, stderr
    data = json.loads(stdout)
    from test_json_docs import compare

    compare("bench plan", data)  # docs/json.md lists exactly these keys
    assert data["complete"] and [r["method"] for r in data["rows"]] == list(METHODS)
    assert all(r["scenario"] == "random" and r["flights"] == 1 for r in data["rows"])
    assert json.loads(out.read_text())["rows"] == data["rows"]
    assert (tmp_path / "fig.png").stat().st_size > 0


def test_cli_refuses_a_missing_planner_and_bad_args(tmp_path):
    from conftest import run_cli

    code, _, stderr = run_cli("bench", "plan", "--quick", "--planner", "no_such_module:fn")
    assert code == 2 and "not available" in stderr
    code, _, stderr = run_cli("bench", "plan", "--quick", "--png", tmp_path / "x.jpg")
    assert code == 2 and ".png" in stderr


def test_physical_bound_keeps_nothing_back(tiny, tmp_path):
    from orange_plan.planning.tour import min_energy_per_m

    ctx = load_context(tiny)
    r = ctx.scenario.mission.sensor_radius_m
    drive = ctx.scenario.battery.usable_J / min_energy_per_m(ctx)
    assert 2 * r * drive + np.pi * r * r < ctx.world.map.free_space.area  # energy-bound here
    assert coverage_bound_m2(ctx) == pytest.approx(2 * r * drive + np.pi * r * r)
    big = load_context(write_world(tmp_path, width_m=40, height_m=30, rated_energy_Wh=50.0,
                                   name="big"))
    assert coverage_bound_m2(big) == pytest.approx(big.world.map.free_space.area)


def test_at_confidence_replaces_the_reserve_rule_for_the_planners():
    from dataclasses import dataclass

    from orange_plan.bench.plan import at_confidence
    from orange_plan.scenario import Mission, Reserve

    seen = []

    def planner(ctx, **kwargs):
        seen.append(ctx.scenario.mission.reserve)
        return None

    mission = Mission(duty_cycle=1.0, sensor_radius_m=1.0, reserve=Reserve("fraction", 0.1))

    @dataclass(frozen=True)
    class Sc:
        mission: Mission

    @dataclass(frozen=True)
    class Ctx:
        scenario: Sc

    ctx = Ctx(Sc(mission))
    at_confidence(planner, 0.95)(ctx, cost="physics")
    at_confidence(planner, None)(ctx, cost="physics")
    assert seen == [Reserve("confidence", 0.95), Reserve("fraction", 0.1)]
