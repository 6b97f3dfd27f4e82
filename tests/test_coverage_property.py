"""Properties of coverage candidates on random rectangles with random box obstacles.

Each example is a W x H rectangle (10 to 40 m by 8 to 30 m) with up to five integer boxes
(which may overlap each other or touch the boundary), a random sensor radius r in
[0.4, 3] m, a random or automatic sweep angle and a random or default longest lane.
Invariants, and why each is stated the way it is:

- Every viewpoint is in free space and every lane segment passes ``world.segments_free``,
  the exact shapely test the planner and simulator use: the robot must be able to stand on
  or drive every candidate. Lanes also run along the sweep angle, and are between
  min(0.5 r, max_lane_m / 2) and ``max_lane_m`` long: runs under 0.5 r are dropped, and a
  longer run is cut into ceil(L / max_lane_m) equal pieces, each longer than max_lane_m / 2.
- A candidate's cells are exactly ``grid.cells_near`` of its own path, so the value the
  planner maximises is about the footprint it will actually drive.
- The union of all candidates covers >= 95 % of the free cells, and the union of their
  exact shapely footprints (``footprint``) covers >= 95 % of the exact free area (an
  independent reference that does not use the grid). Stated for every generated map, not only
  open ones, because the pocket viewpoints fill whatever lanes and the hexagonal lattice
  miss; the 5 % slack is for cells within the 0.02 r clearance of keep-out, which no
  candidate may stand on (the generated boxes are on a 1 m lattice, so there is no slit
  narrower than the clearance, where this could be large).
- Values: 0 <= value_m2 (a count times a positive area), value given a covered mask equals
  the uncovered count times the cell area (so a cell already sensed adds nothing), and the
  value with nothing covered lies within the lattice band of the exact shapely footprint
  area: a cell whose centre is in F lies inside F dilated by delta = cell / sqrt 2, and F
  eroded by delta has all its cells' centres in F, so
  ``A - P delta <= count * cell^2 <= A + P delta + pi delta^2`` per component (A, P: area
  and perimeter of F). The test uses the looser ``P * cell + n_parts * pi * cell^2`` for the
  upper side because a non-convex F can add a little more at its convex corners.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from orange_plan.planning.coverage import coverage_candidates, coverage_grid, footprint
from orange_plan.world.geomap import Map
from orange_plan.world.terrain import World


@st.composite
def cases(draw):
    w = float(draw(st.integers(10, 40)))
    h = float(draw(st.integers(8, 30)))
    boxes = []
    for _ in range(draw(st.integers(0, 5))):
        x0, y0 = draw(st.integers(0, int(w) - 2)), draw(st.integers(0, int(h) - 2))
        bw, bh = draw(st.integers(1, 8)), draw(st.integers(1, 8))
        boxes.append(shapely.box(x0, y0, min(x0 + bw, w - 1), min(y0 + bh, h - 1)))
    r = draw(st.floats(0.4, 3.0))
    angle = draw(st.one_of(st.none(), st.integers(0, 179).map(float)))
    max_lane = draw(st.one_of(st.none(), st.floats(0.5, 20.0)))
    return w, h, tuple(boxes), r, angle, max_lane


def make_world(w, h, boxes) -> World:
    m = Map(shapely.box(0, 0, w, h), boxes, (), (), None, None, None, Path("random"))
    return World(m, 0.03, "default", (0.0, 0.0))


@pytest.mark.timeout(300)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=cases(), seed=st.integers(0, 2**31 - 1))
def test_candidates_are_free_cover_the_map_and_value_is_bounded(case, seed):
    w, h, boxes, r, angle, max_lane = case
    world = make_world(w, h, boxes)
    free = world.map.free_space
    if free.area < 1.0:
        return
    grid = coverage_grid(world, r)
    c = coverage_candidates(world, grid, r, angle_deg=angle, max_lane_m=max_lane)
    lane, view = c.kind == "lane", c.kind == "viewpoint"
    event(f"lanes: {bool(lane.any())}")
    assert np.all(lane | view)

    # Free space.
    assert world.is_free(c.anchor_xy_m[view, 0], c.anchor_xy_m[view, 1]).all()
    np.testing.assert_array_equal(c.start_xy_m[view], c.end_xy_m[view])
    assert np.all(c.length_m[view] == 0)
    if lane.any():
        a, b, length = c.start_xy_m[lane], c.end_xy_m[lane], c.length_m[lane]
        assert world.segments_free(a, b).all()
        np.testing.assert_allclose(length, np.hypot(*(b - a).T), rtol=1e-12, atol=1e-12)
        longest = 10 * r if max_lane is None else max_lane
        assert length.min() >= min(0.5 * r, 0.5 * longest) * (1 - 1e-9)
        assert length.max() <= longest * (1 + 1e-9)
        t = np.radians(c.sweep_angle_deg)
        cross = (b - a) @ np.array([-np.sin(t), np.cos(t)])
        np.testing.assert_allclose(cross, 0.0, atol=1e-9 * max(w, h))

    # Cells are the footprint of the candidate's own path.
    for k in np.random.default_rng(seed).choice(c.n, size=min(c.n, 15), replace=False):
        path = [c.start_xy_m[k]] if view[k] else [c.start_xy_m[k], c.end_xy_m[k]]
        np.testing.assert_array_equal(c.cells[k], grid.cells_near(path, r))

    # Coverage: grid count and exact shapely reference.
    covered = np.zeros(grid.n_cells, dtype=bool)
    covered[np.concatenate(c.cells)] = True
    assert covered.mean() >= 0.95
    sensed = shapely.union_all([footprint(world, [c.start_xy_m[k], c.end_xy_m[k]], r)
                                for k in range(c.n)])
    assert sensed.area >= 0.95 * free.area

    # Values.
    none = np.zeros(grid.n_cells, dtype=bool)
    value = c.value_m2(none, grid)
    assert np.all(value >= 0)
    rng = np.random.default_rng(seed)
    x0, y0 = rng.uniform(0, w), rng.uniform(0, h)
    partly = none.copy()
    partly[grid.cells_in(shapely.box(x0, y0, x0 + w / 3, y0 + h / 3))] = True
    v_partly = c.value_m2(partly, grid)
    assert np.all(v_partly >= 0) and np.all(v_partly <= value)
    expected = [np.count_nonzero(~partly[cells]) * grid.cell_area_m2 for cells in c.cells]
    np.testing.assert_allclose(v_partly, expected)
    np.testing.assert_array_equal(c.value_m2(covered, grid), 0.0)
    for k in np.random.default_rng(seed + 1).choice(c.n, size=min(c.n, 15), replace=False):
        f = footprint(world, [c.start_xy_m[k], c.end_xy_m[k]], r)
        n_parts = max(1, shapely.get_num_geometries(f))
        delta = grid.cell_m / np.sqrt(2)
        assert value[k] >= f.area - f.length * delta - 1e-9
        assert value[k] <= f.area + f.length * grid.cell_m + n_parts * np.pi * grid.cell_m**2
