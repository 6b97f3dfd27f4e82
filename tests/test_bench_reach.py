"""bench.reach / ``orange-plan bench reach`` and the BIT* and grid-reference pieces it uses
(small world, few vertices: checks structure and consistency, never timings)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from conftest import run_cli
from planning_worlds import write_world

from orange_plan.bench.gridref import grid_graph
from orange_plan.context import load_context
from orange_plan.planning.paths import bitstar_path, evaluate_path, refined_path, roadmap_path
from orange_plan.planning.reach import cost_contexts
from orange_plan.planning.roadmap import build_roadmap
from orange_plan.world.rasters import build_rasters

pytestmark = pytest.mark.timeout(60)


@pytest.fixture(scope="module")
def hill(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bench")
    path = write_world(folder, width_m=60, height_m=40, home=(4.0, 20.0), obstacles=[(28, 0, 32, 8)],
                       hill=(30.0, 22.0, 10.0, 6.0), surfaces=[(0, 18, 60, 21, 0.01)])
    ctx = load_context(path)
    fast, exact = cost_contexts(ctx, build_rasters(ctx.world))
    return path, ctx, fast, exact


def test_grid_reference_on_flat_ground_is_the_straight_line(tmp_path):
    ctx = load_context(write_world(tmp_path))
    _, exact = cost_contexts(ctx, build_rasters(ctx.world))
    grid = grid_graph(exact, 2.0, 16, origin_xy=(0.0, 0.0))
    straight = evaluate_path(exact, [[2, 2], [38, 2]], "line")
    assert evaluate_path(exact, grid.path((2, 2), (38, 2)), "grid").energy_J == pytest.approx(
        straight.energy_J, rel=1e-9)
    # the grid field sums the energy model's edge weights (cruise throughout): compare with
    # the straight line's cruise figure, not with its driven profile (ramps and stops on top)
    reference = evaluate_path(replace(exact, accel_max_mps2=None), [[2, 2], [38, 2]], "line")
    assert grid.energies_from((2, 2))[grid.nearest((38, 2))] == pytest.approx(
        reference.energy_J, rel=1e-2)


def test_roadmap_close_to_grid_and_bitstar_is_drivable(hill):
    _, ctx, fast, exact = hill
    rm = build_roadmap(fast, n_vertices=800, seed=4)
    grid = grid_graph(exact, 2.0, 16, origin_xy=(0.0, 0.0))
    ref = evaluate_path(exact, grid.path((4, 20), (56, 20)), "grid").energy_J
    best = roadmap_path(exact, rm, (4.0, 20.0), (56.0, 20.0))
    assert best.energy_J < 1.10 * ref
    bit = bitstar_path(fast, exact, (4.0, 20.0), (56.0, 20.0), seconds=0.3)
    if bit is not None:
        assert ctx.world.segments_free(bit.xy_m[:-1], bit.xy_m[1:]).all()
        assert np.allclose(bit.xy_m[[0, -1]], [[4, 20], [56, 20]])
    refined = refined_path(fast, exact, rm, (4.0, 20.0), (56.0, 20.0), seconds=0.3)
    assert refined.energy_J <= best.energy_J


def test_bench_cli_json(hill):
    path = hill[0]
    code, out, err = run_cli("bench", "reach", path, "--repeats", "1", "--vertices", "300",
                             "--bitstar-s", "0.1", "--json")
    assert code == 0, err
    d = json.loads(out)
    assert d["n_vertices"] == 301 and d["goal_queries"] == 10000
    assert set(d["speed_s"]) == {"50", "200", "1000"}
    for p in d["pairs"]:
        assert p["roadmap_J"] > 0 and p["grid_J"] > 0 and p["shortest_J"] > 0
        assert p["roadmap_vs_grid"] == pytest.approx(p["roadmap_J"] / p["grid_J"])
    code, out, err = run_cli("bench", "reach", path, "--repeats", "0")
    assert code == 2 and "--repeats = 0" in err
