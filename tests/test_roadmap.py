"""planning.roadmap: PRM* geometry, exact edges, asymmetric weights, Dijkstra fields."""

from __future__ import annotations

import numpy as np
import pytest
from planning_worlds import write_world

from orange_plan.context import load_context
from orange_plan.errors import InputError
from orange_plan.planning.reach import cost_contexts
from orange_plan.planning.roadmap import (
    add_vertices,
    build_roadmap,
    energy_field,
    surface_samples,
)
from orange_plan.world.rasters import build_rasters

pytestmark = pytest.mark.timeout(60)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    folder = tmp_path_factory.mktemp("roadmap")
    ctx = load_context(write_world(folder, obstacles=[(10, 5, 14, 25)], ramp=0.1,
                                   reserve={"confidence": 0.95}))
    fast, exact = cost_contexts(ctx, build_rasters(ctx.world))
    return ctx, fast, exact, build_roadmap(fast, n_vertices=300, seed=3)


def test_surface_samples_skip_a_surface_whose_share_rounds_to_zero(tmp_path):
    # 3 samples by area: the 30 x 20 m surface gets floor(3 x 600/601) = 2, the 1 m^2 one none
    ctx = load_context(write_world(tmp_path, surfaces=[(5, 5, 35, 25, 0.001),
                                                       (37, 1, 38, 2, 0.001)]))
    pts = surface_samples(ctx.world, 3, seed=0)
    assert pts.shape == (2, 2)
    assert np.all((pts >= [5, 5]) & (pts <= [35, 25]))


def test_edges_are_collision_free_and_directed_both_ways(setup):
    ctx, _, _, rm = setup
    assert rm.n_vertices == 301 and np.allclose(rm.xy_m[rm.home_index], ctx.world.home_xy_m)
    assert ctx.world.segments_free(rm.xy_m[rm.src], rm.xy_m[rm.dst]).all()
    assert rm.jacobian.shape == (len(rm.src), len(ctx.model.theta))


def test_weights_are_asymmetric_on_the_ramp(setup):
    _, fast, _, _ = setup
    pairs = np.array([[0, 1]])
    xy = np.array([[5.0, 2.0], [25.0, 2.0]])  # eastward = uphill (ramp 0.1)
    e_up, e_down, j_up, _ = fast.costs(xy[pairs[:, 0]], xy[pairs[:, 1]])
    assert e_up[0] > e_down[0] > 0
    assert j_up.shape == (1, len(fast.model.theta))


def test_fields_zero_at_home_and_paths_end_there(setup):
    _, _, _, rm = setup
    to_home = energy_field(rm, rm.home_index, towards=True)
    from_home = energy_field(rm, rm.home_index, towards=False)
    assert to_home.energy_J[rm.home_index] == 0.0 == from_home.energy_J[rm.home_index]
    v = int(np.argmax(np.where(np.isfinite(to_home.energy_J), to_home.energy_J, -1)))
    seq = to_home.path(v)
    assert seq[0] == v and seq[-1] == rm.home_index
    assert from_home.path(v)[0] == rm.home_index and from_home.path(v)[-1] == v
    # Going east (uphill) and back: the field is asymmetric.
    east = rm.xy_m[:, 0] > 35
    assert np.nanmean(from_home.energy_J[east]) > np.nanmean(to_home.energy_J[east])


def test_field_gradient_reproduces_energy(setup):
    ctx, _, _, rm = setup
    f = energy_field(rm, rm.home_index, towards=True)
    ok = np.isfinite(f.energy_J)
    assert np.allclose(f.gradient[ok] @ ctx.model.theta, f.energy_J[ok], rtol=1e-9, atol=1e-6)


def test_field_without_gradient_has_the_same_energies_and_paths(setup):
    _, _, _, rm = setup
    for towards in (True, False):
        full = energy_field(rm, rm.home_index, towards)
        lean = energy_field(rm, rm.home_index, towards, with_gradient=False)
        assert np.array_equal(lean.energy_J, full.energy_J)
        assert np.array_equal(lean.next_vertex, full.next_vertex)
        assert lean.gradient.shape == (rm.n_vertices, 0)


def test_add_vertices_connects_new_points(setup):
    _, fast, _, rm = setup
    more = add_vertices(fast, rm, np.array([[30.0, 20.0], [31.0, 21.0]]))
    assert more.n_vertices == rm.n_vertices + 2
    assert np.any((more.src == rm.n_vertices) & (more.dst == rm.n_vertices + 1))


def test_too_few_vertices(setup):
    _, fast, _, _ = setup
    with pytest.raises(InputError, match="n_vertices"):
        build_roadmap(fast, n_vertices=1)


def test_reverse_costs_equal_costs_of_the_reversed_segment(setup):
    _, fast, exact, _ = setup
    a, b = np.array([[3.0, 4.0], [30.0, 2.0]]), np.array([[25.0, 28.0], [39.0, 29.0]])
    for cost in (fast, exact):
        e_ab, e_ba, _, j_ba = cost.costs(a, b)
        f_ba, f_ab, k_ba, _ = cost.costs(b, a)
        assert np.allclose(e_ba, f_ba, rtol=1e-12) and np.allclose(e_ab, f_ab, rtol=1e-12)
        assert np.allclose(j_ba, k_ba, rtol=1e-12, atol=1e-12)
