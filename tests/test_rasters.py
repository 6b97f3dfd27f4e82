"""world.rasters: grids built once agree with the exact shapely queries."""

from __future__ import annotations

import numpy as np
import pytest
from planning_worlds import write_world

from orange_plan.context import load_context
from orange_plan.errors import InputError
from orange_plan.physics.conditions import Conditions
from orange_plan.physics.pathcost import path_energy, segments_energy, subdivide
from orange_plan.world.rasters import build_rasters


@pytest.fixture
def ctx(tmp_path):
    return load_context(write_world(tmp_path, obstacles=[(10, 5, 14, 25)],
                                    surfaces=[(20, 0, 40, 15, 0.1)], hill=(28, 20, 5.0, 5.0)))


def test_grids_match_exact_queries_away_from_edges(ctx):
    r = build_rasters(ctx.world)
    xy = np.random.default_rng(1).uniform([0, 0], [40, 30], (5000, 2))
    agree_free = r.is_free(*xy.T) == ctx.world.is_free(*xy.T)
    agree_crr = r.crr_at(*xy.T) == ctx.world.crr_at(*xy.T)
    assert agree_free.mean() > 0.99
    assert agree_crr.mean() > 0.99
    assert np.array_equal(r.surface_code_at([30.0, 5.0], [5.0, 25.0]), [0, -1])


def test_shape_and_scalar_lookups(ctx):
    r = build_rasters(ctx.world, cell_m=0.5)
    assert r.free.shape == r.crr.shape == r.surface_code.shape == (61, 81)
    assert len(r.free_rows) == 61 and isinstance(r.free_rows[0][0], bool)
    assert bool(r.is_free(2.0, 2.0)) and not bool(r.is_free(12.0, 15.0))


def test_raster_segment_check(ctx):
    r = build_rasters(ctx.world)
    ok = r.segments_free([[2, 15], [2, 2]], [[30, 15], [8, 28]])
    assert ok.tolist() == [False, True]


def test_fast_subdivide_energy_within_one_percent_of_exact(ctx):
    r = build_rasters(ctx.world)
    path = np.array([[2.0, 2.0], [18.0, 3.0], [35.0, 22.0], [16.0, 28.0]])
    exact = path_energy(ctx.model, ctx.world, path, 1.0, Conditions(0.9)).total_J
    steps = subdivide(ctx.world, path[:-1], path[1:], terrain=r)
    fast = segments_energy(ctx.model, ctx.world, None, None, 1.0, Conditions(0.9),
                           steps=steps).total_J.sum()
    assert fast == pytest.approx(exact, rel=0.01)


def test_bad_cell_size(ctx):
    with pytest.raises(InputError, match="cell_m"):
        build_rasters(ctx.world, cell_m=0.0)
    with pytest.raises(InputError, match="too large"):
        build_rasters(ctx.world, cell_m=0.001, max_cells=1000)
