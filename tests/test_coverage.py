"""Coverage candidates (planning/coverage.py): hand-computed lanes, cell counts, values.

Reference values: a 20 m x 10 m yard swept at 0 degrees with r = 1 m has width W = 10 m, so
K = ceil(W / 2r) = 5 lanes at y = 1, 3, 5, 7, 9 m (r in from each edge, 2r apart), each
clipped to the yard eroded by the 0.02 r clearance: x from 0.02 to 19.98 m, 19.96 m long.
Cell counts are compared with exact areas within the band a lattice count can miss:
``|count * cell^2 - area| <= perimeter * cell / 2``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import shapely
from conftest import REPO, feature, write_map

from orange_plan.errors import InputError
from orange_plan.planning.coverage import (
    Candidates,
    _clip_lines,
    _ring_edges,
    best_sweep_angle_deg,
    coverage_candidates,
    coverage_grid,
    footprint,
)
from orange_plan.world.geomap import Map, load_map
from orange_plan.world.terrain import World

CLEAR = 0.02  # lane clearance for r = 1 m [m]


def box(x0, y0, x1, y1):
    return [[[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]]


def rect_world(folder: Path, width_m=20.0, height_m=10.0, boxes=(), name="rect.geojson") -> World:
    """A rectangle with box obstacles, loaded through the map reader."""
    features = [feature("boundary", "Polygon", box(0, 0, width_m, height_m))]
    features += [feature("obstacle", "Polygon", box(*b)) for b in boxes]
    return World(load_map(write_map(folder, features, name=name)), 0.03, "default",
                 (0.5, 0.5))


def lanes_of(c: Candidates):
    sel = c.kind == "lane"
    return c.start_xy_m[sel], c.end_xy_m[sel], c.length_m[sel]


# --- lanes ------------------------------------------------------------------------------------
def test_rectangle_gives_five_lanes_at_angle_0(tmp_path):
    world = rect_world(tmp_path)
    grid = coverage_grid(world, 1.0)
    c = coverage_candidates(world, grid, 1.0, angle_deg=0, kinds=("lane",), max_lane_m=100)
    a, b, length = lanes_of(c)
    assert c.n == 5 and c.sweep_angle_deg == 0.0
    np.testing.assert_allclose(a, [[CLEAR, y] for y in (1, 3, 5, 7, 9)], atol=1e-9)
    np.testing.assert_allclose(b, [[20 - CLEAR, y] for y in (1, 3, 5, 7, 9)], atol=1e-9)
    np.testing.assert_allclose(length, 20 - 2 * CLEAR)
    np.testing.assert_allclose(c.anchor_xy_m, 0.5 * (a + b))


def test_default_max_lane_chops_each_lane_in_two_equal_pieces(tmp_path):
    world = rect_world(tmp_path)
    c = coverage_candidates(world, coverage_grid(world, 1.0), 1.0, angle_deg=0, kinds=("lane",))
    a, b, length = lanes_of(c)
    # 19.96 m > 10 r = 10 m: ceil(19.96 / 10) = 2 pieces of 9.98 m, joined at x = 10.
    assert c.n == 10
    np.testing.assert_allclose(length, (20 - 2 * CLEAR) / 2)
    np.testing.assert_allclose(np.sort(a[:, 0]), [CLEAR] * 5 + [10.0] * 5)
    np.testing.assert_allclose(b[a[:, 0] < 1, 0], 10.0)


def test_rectangle_at_90_degrees_gives_ten_lanes(tmp_path):
    world = rect_world(tmp_path)
    c = coverage_candidates(world, coverage_grid(world, 1.0), 1.0, angle_deg=90,
                            kinds=("lane",), max_lane_m=100)
    a, b, length = lanes_of(c)
    assert c.n == 10
    np.testing.assert_allclose(np.sort(a[:, 0]), np.arange(1, 20, 2), atol=1e-9)
    np.testing.assert_allclose(length, 10 - 2 * CLEAR)
    np.testing.assert_allclose(np.minimum(a[:, 1], b[:, 1]), CLEAR, atol=1e-9)


def test_uneven_width_spaces_lanes_evenly_at_most_2r(tmp_path):
    world = rect_world(tmp_path, 20.0, 11.0)
    c = coverage_candidates(world, coverage_grid(world, 1.0), 1.0, angle_deg=0,
                            kinds=("lane",), max_lane_m=100)
    # W = 11: K = ceil(5.5) = 6 lanes from y = 1 to y = 10, spaced 9 / 5 = 1.8 m.
    np.testing.assert_allclose(np.sort(c.start_xy_m[:, 1]), 1 + 1.8 * np.arange(6))


def test_obstacle_splits_the_lane_it_cuts(tmp_path):
    world = rect_world(tmp_path, boxes=[(8, 4, 12, 6)])
    c = coverage_candidates(world, coverage_grid(world, 1.0), 1.0, angle_deg=0,
                            kinds=("lane",), max_lane_m=100)
    a, b, length = lanes_of(c)
    mid = np.isclose(a[:, 1], 5.0)
    assert c.n == 6 and mid.sum() == 2
    np.testing.assert_allclose(np.sort(np.r_[a[mid, 0], b[mid, 0]]),
                               [CLEAR, 8 - CLEAR, 12 + CLEAR, 20 - CLEAR], atol=1e-9)
    np.testing.assert_allclose(length[~mid], 20 - 2 * CLEAR)  # y = 3, 7 pass 1 m from the box
    assert world.segments_free(a, b).all()


def test_diagonal_lanes_run_along_the_angle_and_stay_free(tmp_path):
    world = rect_world(tmp_path, 30.0, 30.0, boxes=[(10, 10, 14, 20), (20, 3, 25, 6)])
    c = coverage_candidates(world, coverage_grid(world, 1.5), 1.5, angle_deg=45,
                            kinds=("lane",))
    a, b, length = lanes_of(c)
    d = (b - a) / length[:, None]
    np.testing.assert_allclose(d, np.tile([math.sqrt(0.5), math.sqrt(0.5)], (len(d), 1)),
                               atol=1e-9)
    assert world.segments_free(a, b).all()
    assert length.min() >= 0.75 - 1e-9 and length.max() <= 15 + 1e-9


def test_clip_lines_matches_shapely_intersection():
    poly = shapely.box(0, 0, 40, 30).difference(
        shapely.union_all([shapely.box(5, 5, 12, 9), shapely.Point(25, 15).buffer(6)]))
    edges = _ring_edges(poly)
    for angle in (0.0, 17.0, 45.0, 90.0, 133.0):
        a = math.radians(angle)
        u, n = np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])
        # Off the polygon's edges: a line along an edge is a measure-zero case that shapely
        # keeps (the line lies on the closed polygon) and the half-open rule may drop.
        offsets = np.linspace(-60, 60, 97) + 0.123
        line, t0, t1 = _clip_lines(edges, offsets, u, n)
        ends = np.stack([offsets[:, None] * n - 100 * u, offsets[:, None] * n + 100 * u], axis=1)
        ref = shapely.length(shapely.intersection(shapely.linestrings(ends), poly))
        np.testing.assert_allclose(np.bincount(line, t1 - t0, minlength=len(offsets)), ref,
                                   atol=1e-9)


# --- sweep angle ------------------------------------------------------------------------------
def test_best_sweep_angle_runs_along_the_long_side(tmp_path):
    assert best_sweep_angle_deg(rect_world(tmp_path, 20, 10, name="a.geojson"), 1.0) == 0.0
    assert best_sweep_angle_deg(rect_world(tmp_path, 10, 20, name="b.geojson"), 1.0) == 90.0
    # A square: 0 and 90 tie; ties go to 0.
    assert best_sweep_angle_deg(rect_world(tmp_path, 12, 12, name="c.geojson"), 1.0) == 0.0


def test_best_sweep_angle_follows_a_rotated_strip():
    strip = shapely.affinity.rotate(shapely.box(0, 0, 60, 6), 30, origin=(0, 0))
    world = World(Map(strip, (), (), (), None, None, None, Path("strip")), 0.03, "d",
                  (1, 1))
    assert best_sweep_angle_deg(world, 1.0) == 30.0


# --- the grid ---------------------------------------------------------------------------------
def test_grid_cells_and_free_area(tmp_path):
    world = rect_world(tmp_path, boxes=[(4, 7, 6, 9)])
    grid = coverage_grid(world, 1.0)
    assert grid.cell_m == pytest.approx(1 / 3)
    assert grid.cell_area_m2 == pytest.approx(1 / 9)
    assert grid.free_area_m2 == pytest.approx(196.0)
    # The box edges fall on cell edges, so the count is exact: 1764 cells of 1/9 m^2.
    assert grid.n_cells == 1764
    assert world.is_free(grid.xy_m[:, 0], grid.xy_m[:, 1]).all()


def test_grid_grows_the_cell_to_stay_under_max_cells(tmp_path):
    world = rect_world(tmp_path)
    grid = coverage_grid(world, 1.0, max_cells=500)
    assert grid.n_cells <= 500 and grid.cell_m > 1 / 3
    assert grid.n_cells * grid.cell_area_m2 == pytest.approx(200.0, rel=0.1)


@pytest.mark.parametrize("radius_m", [1.0, 2.0, 3.0])
def test_cells_near_a_point_is_a_disc(tmp_path, radius_m):
    grid = coverage_grid(rect_world(tmp_path), 1.0)
    cells = grid.cells_near([[10.0, 5.0]], radius_m)
    area = math.pi * radius_m**2
    assert abs(len(cells) * grid.cell_area_m2 - area) <= 2 * math.pi * radius_m * grid.cell_m / 2
    assert np.all(np.diff(cells) > 0) and cells.dtype.kind == "i"
    assert np.all(np.hypot(*(grid.xy_m[cells] - [10.0, 5.0]).T) <= radius_m + 1e-12)


def test_cells_near_a_polyline_matches_shapely_distance(tmp_path):
    world = rect_world(tmp_path, 40, 30, boxes=[(10, 10, 14, 20)])
    grid = coverage_grid(world, 1.0)
    rng = np.random.default_rng(3)
    path = np.column_stack([rng.uniform(-5, 45, 12), rng.uniform(-5, 35, 12)])
    path[4] = path[5]  # a repeated vertex is a zero-length segment
    radius = 2.3
    cells = grid.cells_near(path, radius)
    dist = shapely.distance(shapely.points(grid.xy_m), shapely.LineString(path))
    assert np.all(dist[cells] <= radius + 1e-9)
    assert set(np.flatnonzero(dist <= radius - 1e-9)) <= set(cells)


def test_cells_near_a_segment_is_a_capsule(tmp_path):
    grid = coverage_grid(rect_world(tmp_path), 0.3)  # cell 0.1 m
    cells = grid.cells_near([[5.0, 5.0], [15.0, 5.0]], 2.0)
    capsule = 2 * 2 * 10 + math.pi * 4  # 52.57 m^2
    band = (2 * 10 + 2 * math.pi * 2) * grid.cell_m / 2
    assert abs(len(cells) * grid.cell_area_m2 - capsule) <= band


def test_cells_in_a_box(tmp_path):
    grid = coverage_grid(rect_world(tmp_path), 1.0)
    cells = grid.cells_in(shapely.box(2, 2, 6, 4))
    assert len(cells) * grid.cell_area_m2 == pytest.approx(8.0)  # 12 x 6 cells of 1/9 m^2
    assert len(grid.cells_in(shapely.Polygon())) == 0


# --- values -----------------------------------------------------------------------------------
def test_value_counts_overlap_once(tmp_path):
    world = rect_world(tmp_path)
    grid = coverage_grid(world, 0.3)  # cell 0.1 m
    cells = (grid.cells_near([[8.0, 5.0]], 3.0), grid.cells_near([[11.0, 5.0]], 3.0))
    xy = np.array([[8.0, 5.0], [11.0, 5.0]])
    c = Candidates(np.array(["viewpoint"] * 2), xy, xy, xy, np.zeros(2), cells, 0.0)
    covered = np.zeros(grid.n_cells, dtype=bool)
    disc = math.pi * 9
    np.testing.assert_allclose(c.value_m2(covered, grid), [len(cells[0]) * 0.01,
                                                          len(cells[1]) * 0.01])
    covered[cells[0]] = True
    v = c.value_m2(covered, grid)
    # Discs of radius 3 m, centres 3 m apart: lens = 2 R^2 acos(d/2R) - (d/2) sqrt(4R^2 - d^2).
    lens = 18 * math.acos(0.5) - 1.5 * math.sqrt(27)
    assert v[0] == 0.0
    assert v[1] == pytest.approx(disc - lens, abs=2 * math.pi * 3 * grid.cell_m / 2)
    assert v[1] == pytest.approx(len(np.setdiff1d(cells[1], cells[0])) * grid.cell_area_m2)
    union = len(np.union1d(*cells)) * grid.cell_area_m2
    assert c.value_m2(np.zeros(grid.n_cells, bool), grid)[0] + v[1] == pytest.approx(union)


def test_value_of_adjacent_lane_pieces_counts_the_joint_once(tmp_path):
    world = rect_world(tmp_path)
    grid = coverage_grid(world, 1.0)
    c = coverage_candidates(world, grid, 1.0, angle_deg=0, kinds=("lane",))
    first = np.flatnonzero((c.start_xy_m[:, 1] == 1.0) & (c.start_xy_m[:, 0] < 1))[0]
    second = np.flatnonzero((c.start_xy_m[:, 1] == 1.0) & (c.start_xy_m[:, 0] > 1))[0]
    covered = np.zeros(grid.n_cells, dtype=bool)
    covered[c.cells[first]] = True
    v = c.value_m2(covered, grid)
    joint = len(np.intersect1d(c.cells[first], c.cells[second])) * grid.cell_area_m2
    assert joint == pytest.approx(math.pi, abs=2 * math.pi * grid.cell_m / 2)  # disc at x = 10
    assert v[second] == pytest.approx(len(c.cells[second]) * grid.cell_area_m2 - joint)
    assert v[first] == 0.0


def test_region_keeps_candidates_anchored_in_it(tmp_path):
    world = rect_world(tmp_path)
    grid = coverage_grid(world, 1.0)
    everything = coverage_candidates(world, grid, 1.0, angle_deg=0)
    left = coverage_candidates(world, grid, 1.0, angle_deg=0, region=shapely.box(0, 0, 10, 10))
    assert 0 < left.n < everything.n
    assert np.all(left.anchor_xy_m[:, 0] <= 10)
    far = coverage_candidates(world, grid, 1.0, region=shapely.box(100, 100, 101, 101))
    assert far.n == 0 and far.value_m2(np.zeros(grid.n_cells, bool), grid).shape == (0,)


def test_subset_by_mask_and_by_index(tmp_path):
    world = rect_world(tmp_path)
    grid = coverage_grid(world, 1.0)
    c = coverage_candidates(world, grid, 1.0)
    lanes = c.subset(c.kind == "lane")
    assert set(lanes.kind) == {"lane"} and lanes.sweep_angle_deg == c.sweep_angle_deg
    picked = c.subset([3, 0])
    np.testing.assert_array_equal(picked.start_xy_m, c.start_xy_m[[3, 0]])
    covered = np.zeros(grid.n_cells, dtype=bool)
    np.testing.assert_allclose(picked.value_m2(covered, grid), c.value_m2(covered, grid)[[3, 0]])


def test_viewpoints_are_free_points_whose_union_covers_everything(tmp_path):
    world = rect_world(tmp_path, 30, 20, boxes=[(5, 5, 9, 15), (15, 0, 16, 12), (20, 14, 30, 15)])
    grid = coverage_grid(world, 1.0)
    c = coverage_candidates(world, grid, 1.0, kinds=("viewpoint",))
    assert set(c.kind) == {"viewpoint"}
    assert world.is_free(c.anchor_xy_m[:, 0], c.anchor_xy_m[:, 1]).all()
    np.testing.assert_array_equal(c.start_xy_m, c.end_xy_m)
    assert np.all(c.length_m == 0)
    covered = np.zeros(grid.n_cells, dtype=bool)
    covered[np.concatenate(c.cells)] = True
    assert covered.mean() >= 0.99


# --- footprint --------------------------------------------------------------------------------
def test_footprint_areas(tmp_path):
    world = rect_world(tmp_path, boxes=[(4, 7, 6, 9)])
    assert footprint(world, [[10.0, 5.0]], 1.0).area == pytest.approx(math.pi, rel=1e-3)
    assert footprint(world, [[10.0, 5.0], [10.0, 5.0]], 1.0).area == pytest.approx(math.pi,
                                                                                   rel=1e-3)
    line = footprint(world, [[10.0, 3.0], [15.0, 3.0]], 1.0)
    assert line.area == pytest.approx(2 * 5 + math.pi, rel=1e-3)
    # A disc at a box corner loses the quarter inside the box.
    assert footprint(world, [[4.0, 7.0]], 1.0).area == pytest.approx(0.75 * math.pi, rel=1e-3)
    # Clipped by the boundary: a disc centred on the bottom edge keeps its upper half.
    assert footprint(world, [[10.0, 0.0]], 1.0).area == pytest.approx(0.5 * math.pi, rel=1e-3)


# --- bad input --------------------------------------------------------------------------------
@pytest.mark.parametrize("radius", [0, -1.0, float("nan"), float("inf"), "two", None, True])
def test_bad_sensor_radius_is_refused_on_one_line(tmp_path, radius):
    world = rect_world(tmp_path)
    grid = coverage_grid(world, 1.0)
    calls = [lambda: coverage_grid(world, radius), lambda: best_sweep_angle_deg(world, radius),
             lambda: coverage_candidates(world, grid, radius),
             lambda: footprint(world, [[1.0, 1.0]], radius)]
    for call in calls:
        with pytest.raises(InputError, match=r"^sensor_radius_m = .* must be a finite number > 0"):
            call()
    with pytest.raises(InputError, match=r"sensor_radius_m = 0 must be") as err:
        coverage_grid(world, 0)
    assert "\n" not in str(err.value)


def test_bad_arguments_are_refused(tmp_path):
    world = rect_world(tmp_path)
    grid = coverage_grid(world, 1.0)
    with pytest.raises(InputError, match="radius_m = 0 must be"):
        grid.cells_near([[1.0, 1.0]], 0)
    with pytest.raises(InputError, match=r"path_xy_m must have shape \(n, 2\)"):
        grid.cells_near(np.zeros((3, 3)), 1.0)
    with pytest.raises(InputError, match="path_xy_m holds a non-finite"):
        grid.cells_near([[1.0, np.nan]], 1.0)
    with pytest.raises(InputError, match="did you mean 'lane'"):
        coverage_candidates(world, grid, 1.0, kinds=("lanes",))
    with pytest.raises(InputError, match="kinds is empty"):
        coverage_candidates(world, grid, 1.0, kinds=())
    with pytest.raises(InputError, match="max_lane_m = 0 must be"):
        coverage_candidates(world, grid, 1.0, max_lane_m=0)
    with pytest.raises(InputError, match="angle_deg = nan must be a finite number"):
        coverage_candidates(world, grid, 1.0, angle_deg=float("nan"))
    with pytest.raises(InputError, match="grid must be a CoverageGrid"):
        coverage_candidates(world, None, 1.0)
    with pytest.raises(InputError, match="region must be a shapely geometry"):
        coverage_candidates(world, grid, 1.0, region=[0, 0, 1, 1])
    with pytest.raises(InputError, match="max_cells = 0 must be an integer >= 1"):
        coverage_grid(world, 1.0, max_cells=0)
    c = coverage_candidates(world, grid, 1.0)
    with pytest.raises(InputError, match=r"covered_mask has shape \(3,\), expected \(1800,\)"):
        c.value_m2(np.zeros(3, bool), grid)
    with pytest.raises(InputError, match="geometry must be a shapely geometry"):
        grid.cells_in("box")


def test_no_room_for_a_lane_is_refused(tmp_path):
    world = rect_world(tmp_path, 1.2, 0.4)  # maps under 1 m both ways are refused as lon/lat
    grid = coverage_grid(world, 3.0)
    # One mid-line, at best 1.2 - 2 * 0.06 = 1.08 m < 0.5 r: no lane; a viewpoint still fits.
    with pytest.raises(InputError, match="no room for a coverage candidate"):
        coverage_candidates(world, grid, 3.0, kinds=("lane",))
    assert coverage_candidates(world, grid, 3.0).n >= 1


# --- real maps and speed ----------------------------------------------------------------------
@pytest.mark.parametrize("scenario", ["kiwibot_campus", "husky_a200", "ar_drone_wind",
                                      "marine_survey", "rusti_v1_box", "vacuum_home"])
def test_real_scenarios(scenario):
    from orange_plan.context import load_context

    ctx = load_context(REPO / "scenarios" / f"{scenario}.toml")
    world, r = ctx.world, ctx.scenario.mission.sensor_radius_m
    grid = coverage_grid(world, r)
    c = coverage_candidates(world, grid, r)
    lane = c.kind == "lane"
    assert lane.any() and (~lane).any()
    assert world.segments_free(c.start_xy_m[lane], c.end_xy_m[lane]).all()
    assert world.is_free(c.anchor_xy_m[:, 0], c.anchor_xy_m[:, 1]).all()
    covered = np.zeros(grid.n_cells, dtype=bool)
    covered[np.concatenate(c.cells)] = True
    # Cells farther than r from where the robot fits (a gap under furniture narrower than
    # the robot) cannot be sensed; every other cell must be.
    sensable = shapely.distance(world.map.free_space, shapely.points(grid.xy_m)) <= r
    assert covered[sensable].mean() >= 0.99
    assert abs(grid.n_cells * grid.cell_area_m2 / grid.free_area_m2 - 1) < 0.02


def big_world(n_obstacles=300, seed=1) -> World:
    """2 km x 2 km with random boxes of 5 to 40 m."""
    rng = np.random.default_rng(seed)
    centre = rng.uniform(50, 1950, (n_obstacles, 2))
    size = rng.uniform(5, 40, (n_obstacles, 2))
    boxes = tuple(shapely.box(*(c - s / 2), *(c + s / 2)) for c, s in zip(centre, size))
    m = Map(shapely.box(0, 0, 2000, 2000), boxes, (), (), None, None, None, Path("big"))
    return World(m, 0.03, "default", (1.0, 1.0))


def test_large_map_grid_candidates_and_sensing_are_correct():
    """A 2 km map with 300 boxes: every lane candidate is free, the grid stays within its cell
    budget, and the cells a 500-segment tour senses are exactly those within the radius
    (checked on every returned cell and on a sample of the others). How long it takes is a
    benchmark's business, not a test's."""
    world = big_world()
    grid = coverage_grid(world, 5.0)
    c = coverage_candidates(world, grid, 5.0)
    lane = c.kind == "lane"
    assert world.segments_free(c.start_xy_m[lane], c.end_xy_m[lane]).all()
    assert grid.n_cells <= 400_000
    tour = np.random.default_rng(0).uniform(0, 2000, (500, 2))  # ~ 500 km of path
    near = grid.cells_near(tour, 5.0)
    line = shapely.LineString(tour)
    distance = shapely.distance(line, shapely.points(grid.xy_m[near]))
    assert near.size > 1000 and np.all(distance <= 5.0 + 1e-9)
    others = np.setdiff1d(np.arange(grid.n_cells), near)
    sample = np.random.default_rng(1).choice(others, 20_000, replace=False)
    assert np.all(shapely.distance(line, shapely.points(grid.xy_m[sample])) > 5.0 - 1e-9)


def test_angle_is_taken_modulo_180(tmp_path):
    world = rect_world(tmp_path)
    grid = coverage_grid(world, 1.0)
    c = coverage_candidates(world, grid, 1.0, angle_deg=180, kinds=("lane",), max_lane_m=100)
    assert c.sweep_angle_deg == 0.0 and c.n == 5
