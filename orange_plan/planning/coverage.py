"""Coverage candidates for the exploration tour.

The tour planner chooses among *candidates*, pieces of work that each sense part of the free
workspace with a sensor footprint of radius ``r = sensor_radius_m``:

- **lanes**: boustrophedon sweep lines at one angle, spaced at most ``2 r`` apart and ``r``
  in from the free space's extreme edges so their footprints (strips of width ``2 r``) tile
  it, clipped to the free space shrunk by a small clearance, split where keep-out zones cut
  them and chopped into pieces of at most ``max_lane_m`` so a tour can take part of a lane;
- **viewpoints**: points of a hexagonal lattice of spacing ``r sqrt(3)`` (whose discs of
  radius ``r`` cover the plane), plus extra points in the pockets the others miss.

Sensed area is counted on a ``CoverageGrid`` of square cells over the free space, so an area
sensed twice counts once: the value of a candidate given what is already covered is
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
from shapely.geometry import LineString, Point
from shapely.geometry.base import BaseGeometry

from orange_plan.errors import InputError, close_match_hint
from orange_plan.limits import MAX_COVERAGE_CELLS, MAX_COVERAGE_LATTICE_POINTS, smallest_radius_m

CELLS_PER_RADIUS = 3
"""Default cell side is r / 3: a disc of radius r then holds ~28 cells (area error ~ 5 %)."""

LATTICE_PER_CELL = 8
"""The dense lattice over the free space's bounding box may hold this many times max_cells."""

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

HEX_AREA_PER_R2 = 1.5 * math.sqrt(3.0)
"""Area of one viewpoint lattice cell over r^2 (spacing r sqrt 3 by rows 1.5 r apart)."""

_BATCH_POINTS = 2_000_000  # lattice points tested per vectorised batch: bounds memory (~100 MB)


# --- the grid -----------------------------------------------------------------------------
@dataclass(frozen=True)
class CoverageGrid:
    """Free workspace discretised into square cells, to count sensed area without double counting.

    Attributes
    ----------
    cell_m : cell side [m]
    xy_m : (M, 2) centres of the free cells (centre inside the free space), row-major by y [m]
    free_space : the free space (boundary minus keep-out), shapely geometry [m]
    origin_xy_m : lower-left corner of the lattice; cell (ix, iy) has its centre at
        ``origin + (i + 0.5) * cell_m`` [m]
    lattice : (ny, nx) int32, index into ``xy_m`` of lattice cell (iy, ix), -1 where the
        centre is not free
    """

    cell_m: float
    xy_m: np.ndarray
    free_space: BaseGeometry = field(repr=False)
    origin_xy_m: tuple[float, float]
    lattice: np.ndarray = field(repr=False)

    @property
    def n_cells(self) -> int:
        """Number M of free cells."""
        return len(self.xy_m)

    @property
    def cell_area_m2(self) -> float:
        """Area one cell stands for, ``cell_m^2`` [m^2]."""
        return self.cell_m**2

    @property
    def free_area_m2(self) -> float:
        """Exact area of the free space (shapely), not the cell count times the cell area [m^2]."""
        return float(shapely.area(self.free_space))

    def cells_near(self, path_xy_m, radius_m) -> np.ndarray:
        """Cells whose centre lies within ``radius_m`` of a polyline.

        Parameters
        ----------
        path_xy_m : (n, 2) polyline vertices [m]; a single point means a disc
        radius_m : distance from the polyline [m], > 0

        Returns
        -------
        Sorted unique indices into ``xy_m`` (int): ``{i : dist(xy_m[i], path) <= radius_m}``.

        Notes
        -----
        Exact point-to-segment distances, evaluated only on the lattice cells of each
        segment piece's bounding box (pieces at most ``max(2 radius, cell)`` long), so the
        work grows with the area swept, not with the grid.
        """
        xy = _as_path(path_xy_m, "path_xy_m")
        radius = _positive(radius_m, "radius_m")
        a, b = (xy, xy) if len(xy) == 1 else (xy[:-1], xy[1:])
        _, cells = self._near_pairs(a, b, np.zeros(len(a), dtype=np.int64), radius)
        return _unique(cells)

    def cells_in(self, geometry) -> np.ndarray:
        """Sorted indices of the cells whose centre lies in (or on the edge of) a geometry."""
        if not isinstance(geometry, BaseGeometry):
            raise InputError(f"geometry must be a shapely geometry, got {type(geometry).__name__}")
        if geometry.is_empty:
            return np.zeros(0, dtype=np.int64)
        xmin, ymin, xmax, ymax = geometry.bounds
        x, y = self.xy_m[:, 0], self.xy_m[:, 1]
        sel = np.flatnonzero((x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax))
        shapely.prepare(geometry)  # many points against one geometry: index its edges once
        return sel[shapely.intersects_xy(geometry, x[sel], y[sel])]

    def _near_pairs(self, a, b, owner, radius_m: float):
        """(owner, cell) pairs with the cell centre within radius of segment a[k]-b[k].

        Pairs may repeat (a cell near two segments of one owner); callers deduplicate.
        """
        if len(a) == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        a, b, owner = _chop_segments(a, b, owner, max(2.0 * radius_m, self.cell_m))
        # Lattice units: cell (ix, iy) has its centre at integer coordinates (ix, iy).
        qa = (a - self.origin_xy_m) / self.cell_m - 0.5
        qb = (b - self.origin_xy_m) / self.cell_m - 0.5
        rho = radius_m / self.cell_m
        lo = np.ceil(np.minimum(qa, qb) - rho).astype(np.int64)
        hi = np.floor(np.maximum(qa, qb) + rho).astype(np.int64)
        kx, ky = (int(k) for k in (hi - lo).max(axis=0) + 1)
        batch = max(1, _BATCH_POINTS // (kx * ky))
        owners, cells = [], []
        for s in range(0, len(a), batch):
            o, c = self._near_batch(qa[s:s + batch], qb[s:s + batch], lo[s:s + batch], kx, ky,
                                    rho)
            owners.append(owner[s:s + batch][o])
            cells.append(c)
        return np.concatenate(owners), np.concatenate(cells)

    def _near_batch(self, qa, qb, lo, kx: int, ky: int, rho: float):
        """Indices (segment, cell) of one batch; distances in lattice units."""
        ny, nx = self.lattice.shape
        ix = lo[:, 0, None, None] + np.arange(kx)[None, :, None]  # (c, kx, 1)
        iy = lo[:, 1, None, None] + np.arange(ky)[None, None, :]  # (c, 1, ky)
        px, py = ix - qa[:, 0, None, None], iy - qa[:, 1, None, None]
        d = qb - qa
        dx, dy = d[:, 0, None, None], d[:, 1, None, None]
        dd = dx * dx + dy * dy
        t = np.clip((px * dx + py * dy) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
        ex, ey = px - t * dx, py - t * dy
        near = (ex * ex + ey * ey <= rho * rho) & (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        seg, jx, jy = np.nonzero(near)
        cell = self.lattice[lo[seg, 1] + jy, lo[seg, 0] + jx].astype(np.int64)
        keep = cell >= 0
        return seg[keep], cell[keep]


def coverage_grid(world, sensor_radius_m: float,
                  max_cells: int = MAX_COVERAGE_CELLS) -> CoverageGrid:
    """Discretise the free space into square cells of side ~ r / 3.

    Parameters
    ----------
    world : orange_plan.world.terrain.World
    sensor_radius_m : footprint radius r [m], > 0; sets the cell side ``r / 3``
    max_cells : most free cells allowed; the cell grows (coarser counting) to stay under it

    Returns
    -------
    CoverageGrid

    Raises
    ------
    InputError
        Non-positive or non-finite radius, a radius too small for the map
        (``check_sensor_radius``), max_cells < 1, or a free space holding no cell.

    Notes
    -----
    A cell is free when its centre is in the free space. Counted area ``M * cell_m^2``
    differs from the exact free area by at most about ``perimeter * cell_m / 2``.
    """
    r = check_sensor_radius(world, sensor_radius_m)
    if (isinstance(max_cells, bool) or not isinstance(max_cells, (int, np.integer))
            or max_cells < 1):
        raise InputError(f"max_cells = {max_cells!r} must be an integer >= 1")
    free = world.true_map.free_space  # the sensor sees up to the walls, not the robot's keep-away
    area_m2 = float(free.area)
    if area_m2 <= 0:
        raise InputError("the free workspace is empty (boundary entirely inside keep-out zones)")
    xmin, ymin, xmax, ymax = free.bounds
    # Start where the area estimate says the count fits (3 % spare for the edge cells, saving
    # a second pass), then grow until both limits hold.
    cell = max(r / CELLS_PER_RADIUS, math.sqrt(area_m2 / (0.97 * max_cells)))
    shapely.prepare(free)
    while True:
        nx = max(1, math.ceil((xmax - xmin) / cell - 1e-9))
        ny = max(1, math.ceil((ymax - ymin) / cell - 1e-9))
        if nx * ny > LATTICE_PER_CELL * max_cells:  # a thin diagonal workspace: bound memory
            cell *= 1.05 * math.sqrt(nx * ny / (LATTICE_PER_CELL * max_cells))
            continue
        # Centre the lattice on the bounding box so a box workspace is tiled symmetrically.
        origin = (0.5 * (xmin + xmax - nx * cell), 0.5 * (ymin + ymax - ny * cell))
        gx, gy = np.meshgrid(origin[0] + (np.arange(nx) + 0.5) * cell,
                             origin[1] + (np.arange(ny) + 0.5) * cell)
        inside = shapely.contains_xy(free, gx, gy)
        count = int(inside.sum())
        if count <= max_cells:
            break
        cell *= 1.02 * math.sqrt(count / max_cells)
    if count == 0:
        raise InputError(
            f"the free workspace ({area_m2:g} m^2) holds no coverage cell of {cell:g} m: "
            "it is too narrow for this sensor_radius_m"
        )
    lattice = np.full((ny, nx), -1, dtype=np.int32)
    lattice[inside] = np.arange(count, dtype=np.int32)
    xy = np.column_stack([gx[inside], gy[inside]])
    return CoverageGrid(float(cell), xy, free, origin, lattice)


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


def check_sensor_radius(world, sensor_radius_m) -> float:
    """The sensor radius as a float, if the map's candidate lattices fit the limits.

    Parameters
    ----------
    world : orange_plan.world.terrain.World
    sensor_radius_m : footprint radius r [m]

    Returns
    -------
    r [m], finite and > 0.

    Raises
    ------
    InputError
        A radius that is not a finite number > 0, or one so small for the map that the
        viewpoint lattice over the boundary's bounding box (``_hex_shape``; the sweep lanes
        are fewer) would hold more than ``limits.MAX_COVERAGE_LATTICE_POINTS`` points. One
        line naming ``sensor_radius_m``, the limit and the smallest radius this map allows.

    Notes
    -----
    Checked before any lattice, lane or grid is allocated: the lattice has about
    ``A / (2.6 r^2)`` points for a bounding box of area A, so a radius of 1e-9 m on a room
    would have asked for 10^19 of them.
    """
    r = _positive(sensor_radius_m, "sensor_radius_m")
    xmin, ymin, xmax, ymax = world.map.boundary.bounds
    # in floats, where a radius of 1e-300 m gives inf instead of a 10^300-digit integer; at
    # least the ``_hex_shape`` count (its ceil() adds less than one row and one column)
    points = ((xmax - xmin) / (r * math.sqrt(3.0)) + 3.0) * ((ymax - ymin) / (1.5 * r) + 2.0)
    if points > MAX_COVERAGE_LATTICE_POINTS:
        area = (xmax - xmin) * (ymax - ymin)
        least = smallest_radius_m(area, HEX_AREA_PER_R2, MAX_COVERAGE_LATTICE_POINTS)
        raise InputError(
            f"sensor_radius_m = {r:g} m is too small for this map ({xmax - xmin:g} x "
            f"{ymax - ymin:g} m): its coverage lattice would have {points:.3g} points, more "
            f"than the limit of {MAX_COVERAGE_LATTICE_POINTS:,}; use sensor_radius_m >= "
            f"{1.01 * least:.3g} m")
    return r


def footprint(world, path_xy_m, sensor_radius_m):
    """Area a path senses: its ``r``-buffer intersected with the free space (shapely geometry).

    Parameters
    ----------
    world : orange_plan.world.terrain.World
    path_xy_m : (n, 2) polyline [m]; one point (or repeated points) means a disc
    sensor_radius_m : footprint radius r [m], > 0

    Notes
    -----
    ``F = {p : dist(p, path) <= r} intersect free``; arcs are approximated with 32 segments
    per quarter circle (a disc's area within 0.05 %).
    """
    r = _positive(sensor_radius_m, "sensor_radius_m")
    xy = _as_path(path_xy_m, "path_xy_m")
    keep = np.ones(len(xy), dtype=bool)
    keep[1:] = np.any(np.diff(xy, axis=0) != 0, axis=1)  # drop repeated vertices
    xy = xy[keep]
    geom = Point(xy[0]) if len(xy) == 1 else LineString(xy)
    return geom.buffer(r, quad_segs=32).intersection(world.true_map.free_space)


# --- helpers ------------------------------------------------------------------------------
def _positive(value, name: str) -> float:
    """A finite float > 0, or a one-line InputError naming the argument."""
    if isinstance(value, bool):
        raise InputError(f"{name} = {value!r} must be a finite number > 0 [m]")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} = {value!r} must be a finite number > 0 [m]") from None
    if not (math.isfinite(v) and v > 0):
        raise InputError(f"{name} = {value!r} must be a finite number > 0 [m]")
    return v


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


def _as_path(path_xy_m, name: str) -> np.ndarray:
    xy = np.asarray(path_xy_m, dtype=float)
    if xy.ndim == 1 and xy.shape == (2,):
        xy = xy[None, :]
    if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) == 0:
        raise InputError(f"{name} must have shape (n, 2) with n >= 1, got {xy.shape}")
    if not np.all(np.isfinite(xy)):
        raise InputError(f"{name} holds a non-finite coordinate")
    return xy


def _chop_segments(a, b, owner, max_len_m: float):
    """Split each segment into equal pieces of at most max_len_m (keeps bounding boxes small)."""
    d = b - a
    k = np.maximum(1, np.ceil(np.hypot(d[:, 0], d[:, 1]) / max_len_m).astype(np.int64))
    if np.all(k == 1):
        return a, b, owner
    seg = np.repeat(np.arange(len(a)), k)
    j = np.arange(len(seg)) - np.repeat(np.cumsum(k) - k, k)
    f0, f1 = (j / k[seg])[:, None], ((j + 1) / k[seg])[:, None]
    return a[seg] + f0 * d[seg], a[seg] + f1 * d[seg], owner[seg]


def _unique(values) -> np.ndarray:
    """Sorted unique values (sort + mask: numpy 2's hashing np.unique is slower on these)."""
    values = np.sort(values)
    return values[np.concatenate([[True], values[1:] != values[:-1]])]


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
