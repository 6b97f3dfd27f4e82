"""Boustrophedon cell decomposition (planning.cells): the cells partition the free space,
obstacles and steps of the boundary cut it, each cell's lanes follow its shape, the number of
cells is bounded, and joining the cells drives every lane piece once."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import Polygon, box

from orange_plan.planning.cells import (
    CELL_ORDERS,
    MAX_CELLS,
    cell_pieces,
    decompose,
    same_angle_merged,
    swept_cells,
)
from orange_plan.planning.coverage import _lane_offsets

L_SHAPE = Polygon([(0, 0), (100, 0), (100, 20), (20, 20), (20, 120), (0, 120)])
"""A 100 x 20 m arm running east-west and a 20 x 100 m arm on it running north-south."""


def _always_free(a, b):
    return np.ones(len(a), bool)


def _world(keep_away_m: float = 0.0):
    return SimpleNamespace(keep_away_m=keep_away_m)


def _assert_partition(cells, free):
    assert all(c.geom_type == "Polygon" and c.is_valid for c in cells)
    total = sum(c.area for c in cells)
    assert total == pytest.approx(free.area, rel=1e-9)  # no overlaps ...
    union = shapely.union_all(cells)
    assert union.symmetric_difference(free).area <= 1e-9 * free.area  # ... and no gaps


def test_a_box_round_an_obstacle_is_cut_into_four_cells():
    free = box(0, 0, 100, 60).difference(box(40, 20, 60, 40))
    for angle in (0.0, 90.0, 30.0):
        cells = decompose(free, angle, 1.0)
        assert len(cells) == 4
        _assert_partition(cells, free)
    # along x: below and above the obstacle (100 x 20) and beside it (40 x 20), by hand
    areas = sorted(c.area for c in decompose(free, 0.0, 1.0))
    assert areas == pytest.approx([800.0, 800.0, 2000.0, 2000.0])


def test_the_step_of_an_l_cuts_it_in_two():
    cells = decompose(L_SHAPE, 0.0, 1.0)
    assert len(cells) == 2
    _assert_partition(cells, L_SHAPE)
    assert sorted(np.round(c.bounds, 9).tolist() for c in cells) == [[0, 0, 100, 20],
                                                                       [0, 20, 20, 120]]


def test_each_cell_of_an_l_is_swept_along_its_length():
    cells = swept_cells(_world(), decompose(L_SHAPE, 0.0, 2.0), 2.0, None, _always_free)
    assert len(cells) == 2
    by_height = {round(c.polygon.bounds[3]): c for c in cells}
    east_west, north_south = by_height[20], by_height[120]
    assert east_west.angle_deg == pytest.approx(0.0)
    assert north_south.angle_deg == pytest.approx(90.0)
    for cell, along in ((east_west, (1.0, 0.0)), (north_south, (0.0, 1.0))):
        for lane in cell.lanes:
            for a, b in lane:
                d = (b - a) / np.hypot(*(b - a))
                assert abs(d @ np.array(along)) == pytest.approx(1.0)
    # 20 m wide arms, lanes 2 r = 4 m apart: 5 lanes each, one piece per lane
    assert [len(c.lanes) for c in (east_west, north_south)] == [5, 5]
    assert all(len(lane) == 1 for c in cells for lane in c.lanes)


def test_per_cell_angles_need_fewer_lane_pieces_than_any_one_angle_on_an_l():
    r = 2.0
    cells = swept_cells(_world(), decompose(L_SHAPE, 0.0, r), r, None, _always_free)
    per_cell = sum(len(lane) for c in cells for lane in c.lanes)
    for angle in range(0, 180, 5):
        whole = swept_cells(_world(), [L_SHAPE], r, float(angle), _always_free, L_SHAPE)
        assert sum(len(lane) for c in whole for lane in c.lanes) > per_cell


def test_neighbours_sharing_an_angle_merge_the_others_do_not():
    two_rooms = [box(0, 0, 50, 10), box(50, 0, 100, 10)]  # one long east-west corridor
    cells, angles = same_angle_merged(two_rooms, 1.0)
    assert len(cells) == 1 and angles == [0.0]
    cells, angles = same_angle_merged(decompose(L_SHAPE, 0.0, 2.0), 2.0)
    assert sorted(angles) == [0.0, 90.0]


def test_whole_map_lanes_cut_into_cells_keep_the_whole_maps_offsets():
    free = box(0, 0, 100, 60).difference(box(40, 20, 60, 40))
    cells = swept_cells(_world(), decompose(free, 0.0, 3.0), 3.0, 0.0, _always_free, free)
    offsets = _lane_offsets(0.0, 60.0, 3.0)
    ys = {round(float(p[0, 1]), 6) for c in cells for lane in c.lanes for p in lane}
    assert ys <= {round(float(y), 6) for y in offsets}


@st.composite
def obstacle_maps(draw):
    w, h = draw(st.floats(40, 200)), draw(st.floats(30, 150))
    holes = []
    for _ in range(draw(st.integers(0, 6))):
        x, y = draw(st.floats(2, w - 12)), draw(st.floats(2, h - 12))
        holes.append(box(x, y, x + draw(st.floats(1, 10)), y + draw(st.floats(1, 10))))
    free = box(0, 0, w, h).difference(shapely.union_all(holes)) if holes else box(0, 0, w, h)
    return free, draw(st.floats(0, 180)), draw(st.floats(0.5, 5))


@settings(max_examples=60, deadline=None)
@given(case=obstacle_maps())
def test_the_cells_partition_the_free_space(case):
    free, angle, r = case
    cells = decompose(free, angle, r)
    assert 1 <= len(cells) <= MAX_CELLS
    _assert_partition(cells, free)


def test_many_obstacles_give_at_most_max_cells():
    holes = [box(10 + 20 * i, 10 + 20 * j, 15 + 20 * i + j % 3, 14 + 20 * j)
             for i in range(15) for j in range(15)]
    free = box(0, 0, 310, 310).difference(shapely.union_all(holes))
    cells = decompose(free, 10.0, 0.5)
    assert len(cells) == MAX_CELLS
    _assert_partition(cells, free)


@pytest.mark.parametrize("how", (*CELL_ORDERS, "in"))
def test_joining_the_cells_drives_every_piece_once(how):
    free = box(0, 0, 100, 60).difference(box(40, 20, 60, 40))
    cells = swept_cells(_world(), decompose(free, 0.0, 2.0), 2.0, None, _always_free)
    pieces = cell_pieces(cells, how, (0.0, 0.0))
    want = sorted(tuple(sorted(map(tuple, p.round(9)))) for c in cells for lane in c.lanes
                  for p in lane)
    got = sorted(tuple(sorted(map(tuple, p.round(9)))) for p in pieces)
    assert got == want
    if how == "out":  # the first cell is the one nearest home
        first = np.asarray(pieces[0])
        assert min(np.hypot(*first.T)) < 10.0
