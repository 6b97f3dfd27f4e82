"""planning.paths: roadmap paths are drivable and their energy is path_energy's."""

from __future__ import annotations

import numpy as np
import pytest
from planning_worlds import write_world

from orange_plan.context import load_context
from orange_plan.errors import PlanningError
from orange_plan.physics.pathcost import path_energy
from orange_plan.planning.paths import clean_polyline, path_gradient, roadmap_path
from orange_plan.planning.reach import cost_contexts
from orange_plan.planning.roadmap import build_roadmap
from orange_plan.world.rasters import build_rasters

pytestmark = pytest.mark.timeout(60)


@pytest.fixture(scope="module")
def hill(tmp_path_factory):
    """A 12 m hill between home and the goal: going round it is cheaper than over it."""
    folder = tmp_path_factory.mktemp("paths")
    ctx = load_context(write_world(folder, width_m=60, height_m=40, home=(5.0, 20.0),
                                   hill=(30.0, 20.0, 12.0, 6.0), turn=0.5))
    fast, exact = cost_contexts(ctx, build_rasters(ctx.world))
    return ctx, exact, build_roadmap(fast, n_vertices=600, seed=5)


def test_energy_path_is_exact_and_drivable(hill):
    ctx, exact, rm = hill
    p = roadmap_path(exact, rm, (5.0, 20.0), (55.0, 20.0))
    again = path_energy(ctx.model, ctx.world, p.xy_m, exact.speed_mps, exact.conditions,
                        exact.accel_max_mps2)
    assert p.energy_J == pytest.approx(again.total_J, rel=1e-12)
    assert ctx.world.segments_free(p.xy_m[:-1], p.xy_m[1:]).all()
    assert np.allclose(p.xy_m[[0, -1]], [[5, 20], [55, 20]])


def test_energy_path_beats_shortest_over_the_hill(hill):
    _, exact, rm = hill
    best = roadmap_path(exact, rm, (5.0, 20.0), (55.0, 20.0))
    short = roadmap_path(exact, rm, (5.0, 20.0), (55.0, 20.0), weight="length")
    assert short.length_m < best.length_m
    assert best.energy_J < 0.95 * short.energy_J


def test_path_gradient_reproduces_energy_with_turning(hill):
    ctx, exact, rm = hill
    p = roadmap_path(exact, rm, (5.0, 20.0), (40.0, 35.0))
    g = path_gradient(exact, p.xy_m)
    assert g @ ctx.model.theta == pytest.approx(p.energy_J, rel=1e-9)
    assert g[ctx.model.names.index("turn_J_per_rad")] > 0


def test_clean_polyline_drops_repeats():
    out = clean_polyline([[0, 0], [0, 0], [1, 0], [1, 0]])
    assert out.tolist() == [[0, 0], [1, 0]]
    assert clean_polyline([[2, 3]]).shape == (2, 2)


def test_unconnected_points(tmp_path):
    ctx = load_context(write_world(tmp_path, obstacles=[(18, 0, 22, 30)]))
    fast, exact = cost_contexts(ctx, build_rasters(ctx.world))
    rm = build_roadmap(fast, n_vertices=100, seed=1)
    with pytest.raises(PlanningError, match="no roadmap path"):
        roadmap_path(exact, rm, (2.0, 2.0), (35.0, 15.0))
