"""Coverage candidates for the exploration tour.

The tour planner chooses among *candidates*, pieces of work that each sense part of the free
workspace with a sensor footprint of radius ``r = sensor_radius_m``:

- **lanes**: boustrophedon sweep lines at one angle, spaced at most ``2 r`` apart and ``r``
  in from the free space's extreme edges so their footprints (strips of width ``2 r``) tile
  it, clipped to the free space shrunk by a small clearance, split where keep-out zones cut
  them and chopped into pieces of at most ``max_lane_m`` so a tour can take part of a lane;
- **viewpoints**: points of a hexagonal lattice of spacing ``r sqrt(3)`` (whose discs of
  radius ``r`` cover the plane), plus extra points in the pockets the others miss.

Sensed area is counted on a ``CoverageGrid`` of square cells over the free space
(``planning.sensing``), so an area sensed twice counts once: the value of a candidate given what is already covered is
``|cells(candidate) minus covered| * cell_m^2``. A cell belongs to the footprint when its
centre lies within ``r`` of the candidate's path and in the free space (line of sight is not
modelled: the sensor sees across a thin wall).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from orange_plan.errors import InputError, close_match_hint
from orange_plan.planning.sensing import (
    CELLS_PER_RADIUS as CELLS_PER_RADIUS,
)
from orange_plan.planning.sensing import HEX_AREA_PER_R2 as HEX_AREA_PER_R2
from orange_plan.planning.sensing import (
    CoverageGrid,
    _chop_segments,
    _positive,
    _unique,
)
from orange_plan.planning.sensing import check_sensor_radius as check_sensor_radius
from orange_plan.planning.sensing import coverage_grid as coverage_grid
from orange_plan.planning.sensing import footprint as footprint

LANE_CLEARANCE_FRACTION = 0.02
"""Lanes and viewpoints keep this fraction of r from keep-out zones and the boundary, so an
exact segment test never sees a lane touching an obstacle."""

MIN_LANE_FRACTION = 0.5
"""Lane pieces shorter than this fraction of r are dropped (a viewpoint covers them)."""

DEFAULT_MAX_LANE_FRACTION = 10.0
"""Default longest lane piece, as a multiple of r."""

ANGLE_STEP_DEG = 5.0
"""Sweep angles tried by ``best_sweep_angle_deg``: 0, 5, ..., 175 degrees."""

POCKET_ROUNDS = 4
"""Rounds of extra viewpoints placed on cells no candidate senses."""

KINDS = ("lane", "viewpoint")




# --- candidates ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Candidates:
    """Coverage candidates: lanes and viewpoints, with the cells each one senses.

    Attributes
    ----------
    kind : (N,) str, "viewpoint" or "lane"
    start_xy_m : (N, 2) entry point [m]
    end_xy_m : (N, 2) exit point (== start for a viewpoint); a lane may be driven either way [m]
    anchor_xy_m : (N, 2) representative point (the viewpoint, a lane's midpoint) [m]
    length_m : (N,) horizontal length driven inside the candidate (0 for a viewpoint) [m]
    cells : N sorted int arrays: grid cells the candidate senses (footprint and free space)
    sweep_angle_deg : lane direction, degrees counter-clockwise from +x, in [0, 180)
    """

    kind: np.ndarray
    start_xy_m: np.ndarray
    end_xy_m: np.ndarray
    anchor_xy_m: np.ndarray
    length_m: np.ndarray
    cells: tuple
    sweep_angle_deg: float
    _owner: np.ndarray = field(init=False, repr=False, compare=False)
    _flat: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        # Flattened (candidate, cell) pairs, built once: value_m2 is called in the planner's loop.
        sizes = np.fromiter((len(c) for c in self.cells), dtype=np.int64, count=len(self.cells))
        flat = np.concatenate(self.cells) if self.cells else np.zeros(0, dtype=np.int64)
        object.__setattr__(self, "_owner", np.repeat(np.arange(len(sizes)), sizes))
        object.__setattr__(self, "_flat", flat.astype(np.int64, copy=False))

    @property
    def n(self) -> int:
        """Number N of candidates."""
        return len(self.kind)

    def value_m2(self, covered_mask, grid: CoverageGrid) -> np.ndarray:
        """New area each candidate would sense [m^2], shape (N,).

        Parameters
        ----------
        covered_mask : (M,) bool, True for cells already sensed
        grid : the CoverageGrid the candidates were built on

        Notes
        -----
        ``value_k = |{i in cells_k : not covered_i}| * cell_m^2``: an already sensed cell adds
        nothing, so overlapping candidates are not counted twice.
        """
        covered = np.asarray(covered_mask)
        if covered.shape != (grid.n_cells,):
            raise InputError(
                f"covered_mask has shape {covered.shape}, expected ({grid.n_cells},) (one per cell)"
            )
        new = ~covered.astype(bool)[self._flat]
        return np.bincount(self._owner, weights=new, minlength=self.n) * grid.cell_area_m2

    def subset(self, keep) -> Candidates:
        """The candidates selected by a boolean mask (N,) or by integer indices (order kept)."""
        keep = np.asarray(keep)
        idx = np.flatnonzero(keep) if keep.dtype == bool else keep.astype(np.int64).ravel()
        if keep.dtype == bool and keep.shape != (self.n,):
            raise InputError(f"keep mask has shape {keep.shape}, expected ({self.n},)")
        return Candidates(self.kind[idx], self.start_xy_m[idx], self.end_xy_m[idx],
                          self.anchor_xy_m[idx], self.length_m[idx],
                          tuple(self.cells[i] for i in idx), self.sweep_angle_deg)


def best_sweep_angle_deg(world, sensor_radius_m) -> float:
    """Sweep angle needing the fewest lanes over the free space.

    Parameters
    ----------
    world : orange_plan.world.terrain.World
    sensor_radius_m : footprint radius r [m], > 0

    Returns
    -------
    The angle in {0, 5, ..., 175} degrees (counter-clockwise from +x) minimising the number of
    lane pieces; ties go to the smallest angle.

    Notes
    -----
    At angle a the lanes are the lines ``s = s_k`` across the normal ``n = (-sin a, cos a)``
    (see ``coverage_candidates``). A line crosses the free space's rings at an even number of
    points and the pieces are half of them: a ring edge with normal projections ``lo <= hi``
    is crossed by ``s_k`` when ``lo <= s_k < hi``, counted for all lines by binary search.
    Each piece is a turn the tour must make, so fewer pieces means shorter, cheaper tours.
    """
    r = check_sensor_radius(world, sensor_radius_m)
    return _best_angle(world.true_map.free_space, r)


def coverage_candidates(world, grid: CoverageGrid, sensor_radius_m: float,
                        angle_deg: float | None = None, kinds=KINDS,
                        max_lane_m: float | None = None, region=None) -> Candidates:
    """Lanes and viewpoints over the free space, each with the grid cells it senses.

    Parameters
    ----------
    world : orange_plan.world.terrain.World (the one ``grid`` was built from)
    grid : CoverageGrid from ``coverage_grid(world, ...)``
    sensor_radius_m : footprint radius r [m], > 0
    angle_deg : lane direction, degrees counter-clockwise from +x (taken modulo 180);
        None: ``best_sweep_angle_deg``
    kinds : which kinds to generate, a subset of ("lane", "viewpoint")
    max_lane_m : longest lane piece [m]; None: ``10 r``
    region : optional shapely geometry; only candidates whose anchor lies in it are returned
        (the planner passes the energy-reachable area)

    Returns
    -------
    Candidates: lanes first (in sweep order), then viewpoints.

    Raises
    ------
    InputError
        Bad radius (or one too small for the map: ``check_sensor_radius``), angle, kinds, max_lane_m or region, or a free space with room for no
        candidate of the requested kinds (before the region filter; an empty region gives an
        empty result).

    Notes
    -----
    Lanes at angle a run along ``u = (cos a, sin a)`` at offsets ``s_k`` along
    ``n = (-sin a, cos a)``: with the free space spanning ``[s_min, s_max]``, width
    ``W = s_max - s_min``, there are ``K = ceil(W / 2r)`` lanes from ``s_min + r`` to
    ``s_max - r``, spaced ``(W - 2r) / (K - 1) <= 2r`` (one mid-line when ``W <= 2r``), so
    their footprints tile the width. Lines are clipped to the robot's free space
    (``world.map``: the map inflated by the robot's keep-away) eroded by ``0.02 r``, split
    where keep-out cuts them, pieces shorter than ``0.5 r`` dropped, and each piece cut into
    ``ceil(L / max_lane_m)`` equal parts (so a part is at least ``min(0.5 r, max_lane_m / 2)``
    long).

    Viewpoints are the points of a hexagonal lattice (spacing ``r sqrt(3)``, rows ``1.5 r``
    apart: its covering radius is exactly r) inside the eroded free space; then, up to four
    times, free cells no candidate senses are bucketed in ``r x r`` squares and one extra
    viewpoint is placed on the uncovered cell nearest each bucket's centroid (moved to the
    nearest point of the eroded free space if that cell is within the clearance).
    """
    r = check_sensor_radius(world, sensor_radius_m)
    kinds = _kinds(kinds)
    if not isinstance(grid, CoverageGrid):
        raise InputError(
            f"grid must be a CoverageGrid (from coverage_grid), got {type(grid).__name__}"
        )
    max_lane = (DEFAULT_MAX_LANE_FRACTION * r if max_lane_m is None
                else _positive(max_lane_m, "max_lane_m"))
    if region is not None and not isinstance(region, BaseGeometry):
        raise InputError(f"region must be a shapely geometry or None, got {type(region).__name__}")
    free = grid.free_space
    # A lane may be driven either way, so angles a and a + 180 are the same sweep.
    angle = _best_angle(free, r) if angle_deg is None else _finite(angle_deg, "angle_deg") % 180.0
    # Lanes are spaced over what the sensor sees but driven where the robot fits.
    inner = world.map.free_space.buffer(-LANE_CLEARANCE_FRACTION * r)
    shapely.prepare(inner)

    parts = []
    if "lane" in kinds:
        start, end, ok = _lanes(world, free, inner, angle, r, max_lane)
        # The eroded polygon keeps lanes off keep-out; the exact test guards against round-off.
        start, end = start[ok], end[ok]
        owner, cells = grid._near_pairs(start, end, np.arange(len(start)), r)
        parts.append(("lane", start, end, _group(owner, cells, len(start))))
    if "viewpoint" in kinds:
        pts = _hex_points(inner, r)
        owner, cells = grid._near_pairs(pts, pts, np.arange(len(pts)), r)
        parts.append(("viewpoint", pts, pts, _group(owner, cells, len(pts))))
        covered = np.zeros(grid.n_cells, dtype=bool)
        for *_, groups in parts:
            if groups:
                covered[np.concatenate(groups)] = True
        pts, groups = _pocket_viewpoints(grid, inner, covered, r)
        parts.append(("viewpoint", pts, pts, groups))

    candidates = _assemble(parts, angle)
    if candidates.n == 0:
        raise InputError(
            f"the free workspace has no room for a coverage candidate of kinds {list(kinds)} "
            f"with sensor_radius_m = {r:g} (lanes need {MIN_LANE_FRACTION * r:g} m of free run)"
        )
    if region is not None:
        shapely.prepare(region)
        anchor = candidates.anchor_xy_m
        candidates = candidates.subset(shapely.intersects_xy(region, anchor[:, 0], anchor[:, 1]))
    return candidates


# --- helpers ------------------------------------------------------------------------------
def _finite(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} = {value!r} must be a finite number") from None
    if not math.isfinite(v):
        raise InputError(f"{name} = {value!r} must be a finite number")
    return v


def _kinds(kinds) -> tuple[str, ...]:
    if isinstance(kinds, str):
        kinds = (kinds,)
    kinds = tuple(kinds)
    for k in kinds:
        if k not in KINDS:
            raise InputError(
                f"kinds: unknown candidate kind {k!r} (allowed: {', '.join(KINDS)})"
                + close_match_hint(str(k), KINDS)
            )
    if not kinds:
        raise InputError(f"kinds is empty; give at least one of {', '.join(KINDS)}")
    return kinds


def _group(owner, cells, n: int) -> tuple:
    """Per-owner sorted unique cell arrays from (owner, cell) pairs."""
    if n == 0:
        return ()
    m = np.int64(cells.max() + 1) if len(cells) else np.int64(1)
    key = _unique(owner.astype(np.int64) * m + cells)
    own, cell = key // m, key % m
    bounds = np.searchsorted(own, np.arange(n + 1)).tolist()
    return tuple(cell[i:j] for i, j in pairwise(bounds))  # np.split is 10x slower


def _lane_offsets(s_min: float, s_max: float, r: float) -> np.ndarray:
    """Normal offsets of the lanes: r in from both edges, at most 2 r apart."""
    width = s_max - s_min
    n = max(1, math.ceil(width / (2.0 * r) - 1e-9))
    if n == 1:
        return np.array([0.5 * (s_min + s_max)])
    return s_min + r + np.arange(n) * (width - 2.0 * r) / (n - 1)


def _directions(angle_deg: float):
    a = math.radians(angle_deg)
    return np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])


def _ring_edges(geom) -> np.ndarray:
    """(E, 2, 2) edges of every ring of a polygonal geometry."""
    rings = shapely.get_rings(shapely.get_parts(geom))
    xy, ring = shapely.get_coordinates(rings, return_index=True)
    same = ring[1:] == ring[:-1]
    return np.stack([xy[:-1][same], xy[1:][same]], axis=1)


def _best_angle(free, r: float) -> float:
    edges = _ring_edges(free)
    if len(edges) == 0:
        return 0.0
    best, best_count = 0.0, None
    for angle in np.arange(0.0, 180.0, ANGLE_STEP_DEG):
        _, nrm = _directions(angle)
        s = edges @ nrm  # (E, 2) normal projection of both ends
        lo, hi = np.sort(np.min(s, axis=1)), np.sort(np.max(s, axis=1))
        offsets = _lane_offsets(float(lo[0]), float(hi[-1]), r)
        crossings = (np.searchsorted(lo, offsets, side="right")
                     - np.searchsorted(hi, offsets, side="right"))
        count = int(crossings.sum()) // 2
        if best_count is None or count < best_count:  # strict: ties keep the smaller angle
            best, best_count = float(angle), count
    return best


def _lanes(world, free, inner, angle_deg: float, r: float, max_lane_m: float):
    """Start and end points (L, 2) of the lane pieces, in sweep order."""
    u, nrm = _directions(angle_deg)
    s = shapely.get_coordinates(free) @ nrm
    offsets = _lane_offsets(float(s.min()), float(s.max()), r)
    line, t_in, t_out = _clip_lines(_ring_edges(inner), offsets, u, nrm)
    keep = t_out - t_in >= MIN_LANE_FRACTION * r
    line, t_in, t_out = line[keep], t_in[keep], t_out[keep]
    a = offsets[line, None] * nrm + t_in[:, None] * u
    b = offsets[line, None] * nrm + t_out[:, None] * u
    a, b, _ = _chop_segments(a, b, np.zeros(len(a), dtype=np.int64), max_lane_m * (1 + 1e-12))
    return a, b, _segments_free(world, a, b)


def _segments_free(world, a, b) -> np.ndarray:
    """``world.segments_free`` with prepared geometries (8,000 lanes: 0.05 s instead of 0.2 s)."""
    if len(a) == 0:
        return np.zeros(0, dtype=bool)
    lines = shapely.linestrings(np.stack([a, b], axis=1))
    boundary, keep_out = world.map.boundary, world.map.keep_out
    shapely.prepare(boundary)
    ok = shapely.covers(boundary, lines)
    if not keep_out.is_empty:
        shapely.prepare(keep_out)
        ok &= ~shapely.intersects(keep_out, lines)
    return ok


def _clip_lines(edges, offsets, u, nrm):
    """Pieces of the lines ``{p : p . nrm = offsets[k]}`` inside a polygon given by its edges.

    Returns (line index, entry t, exit t) per piece, t measured along ``u``, sorted by line
    then t. An edge whose normal projections are ``lo <= hi`` crosses line k when
    ``lo <= offsets[k] < hi``: this half-open rule counts a line through a vertex once (or
    twice at an extremum), so every line crosses the closed rings an even number of times and
    sorted crossings pair up as (in, out). A line running exactly along an edge is a
    measure-zero case that may come out on either side of that edge (both are at least the
    clearance away from keep-out). It replaces shapely.intersection, which re-reads
    the whole polygon for each line (0.6 s for 400 lines on a map with 300 obstacles).
    """
    if len(edges) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0)
    s, t = edges @ nrm, edges @ u  # (E, 2): both ends of each edge
    first = np.searchsorted(offsets, s.min(axis=1), side="left")
    stop = np.searchsorted(offsets, s.max(axis=1), side="left")
    n = stop - first  # lines crossed by each edge: a contiguous range, offsets being sorted
    edge = np.repeat(np.arange(len(edges)), n)
    line = first[edge] + np.arange(len(edge)) - np.repeat(np.cumsum(n) - n, n)
    frac = (offsets[line] - s[edge, 0]) / (s[edge, 1] - s[edge, 0])
    tc = t[edge, 0] + frac * (t[edge, 1] - t[edge, 0])
    order = np.lexsort((tc, line))
    line, tc = line[order], tc[order]
    return line[0::2], tc[0::2], tc[1::2]


def _hex_shape(bounds, r: float) -> tuple[int, int]:
    """Columns and rows (nx, ny) of the hexagonal lattice (spacing r sqrt 3, rows 1.5 r
    apart) over a bounding box (xmin, ymin, xmax, ymax) [m]."""
    xmin, ymin, xmax, ymax = bounds
    return (math.ceil((xmax - xmin) / (r * math.sqrt(3.0))) + 2,
            math.ceil((ymax - ymin) / (1.5 * r)) + 1)


def _hex_points(inner, r: float) -> np.ndarray:
    """Hexagonal lattice (spacing r sqrt 3, covering radius r) points inside ``inner``."""
    if inner.is_empty:
        return np.zeros((0, 2))
    xmin, ymin, _, ymax = inner.bounds
    dx, dy = r * math.sqrt(3.0), 1.5 * r
    nx, ny = _hex_shape(inner.bounds, r)
    rows = ymin + (np.arange(ny) - 0.5 * (ny - 1 - (ymax - ymin) / dy)) * dy
    cols = xmin - 0.5 * dx + np.arange(nx) * dx
    gx, gy = np.meshgrid(cols, rows)
    gx = gx + 0.5 * dx * (np.arange(ny) % 2)[:, None]  # odd rows shift half a spacing
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    return pts[shapely.contains_xy(inner, pts[:, 0], pts[:, 1])]


def _pocket_viewpoints(grid: CoverageGrid, inner, covered, r: float):
    """Extra viewpoints on free cells no candidate senses; updates ``covered`` in place.

    A representative cell within the clearance of keep-out (a slit along a wall) is moved to
    the nearest point of the eroded free space, which still senses it when within r.
    """
    points, groups = [], []
    for _ in range(POCKET_ROUNDS):
        miss = np.flatnonzero(~covered)
        if len(miss) == 0 or inner.is_empty:
            break
        pts = grid.xy_m[miss[_bucket_representatives(grid.xy_m[miss], r)]]
        off = ~shapely.contains_xy(inner, pts[:, 0], pts[:, 1])
        if off.any():
            nearest = shapely.get_coordinates(
                shapely.get_point(shapely.shortest_line(inner, shapely.points(pts[off])), 0))
            pts[off] = nearest
        owner, cells = grid._near_pairs(pts, pts, np.arange(len(pts)), r)
        if not np.any(~covered[cells]):
            break  # nothing left that a viewpoint in the eroded free space can sense
        covered[cells] = True
        points.append(pts)
        groups.extend(_group(owner, cells, len(pts)))
    pts = np.concatenate(points) if points else np.zeros((0, 2))
    return pts, tuple(groups)


def _bucket_representatives(xy, size_m: float) -> np.ndarray:
    """Per square bucket of side size_m, the index of the point nearest the bucket's centroid."""
    key = np.floor(xy / size_m).astype(np.int64)
    _, bucket = np.unique(key, axis=0, return_inverse=True)
    bucket = bucket.ravel()
    count = np.bincount(bucket)
    centroid = np.column_stack([np.bincount(bucket, xy[:, 0]), np.bincount(bucket, xy[:, 1])])
    centroid /= count[:, None]
    dist = np.hypot(*(xy - centroid[bucket]).T)
    order = np.lexsort((dist, bucket))
    first = np.ones(len(order), dtype=bool)
    first[1:] = bucket[order][1:] != bucket[order][:-1]
    return order[first]


def _assemble(parts, angle_deg: float) -> Candidates:
    kind, start, end, cells = [], [], [], []
    for k, a, b, groups in parts:
        kind.append(np.full(len(a), k, dtype="<U9"))
        start.append(a)
        end.append(b)
        cells.extend(groups)
    start = np.concatenate(start) if start else np.zeros((0, 2))
    end = np.concatenate(end) if end else np.zeros((0, 2))
    kind = np.concatenate(kind) if kind else np.zeros(0, dtype="<U9")
    return Candidates(kind, start, end, 0.5 * (start + end), np.hypot(*(end - start).T),
                      tuple(cells), float(angle_deg))
