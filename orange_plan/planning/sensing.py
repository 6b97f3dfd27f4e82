"""Sensed area: the coverage grid and the sensor footprint.

Sensed area is counted on a ``CoverageGrid`` of square cells over the free space, so an area
sensed twice counts once. A cell belongs to a path's footprint when its centre lies within
``r = sensor_radius_m`` of the path and in the free space (line of sight is not modelled: the
sensor sees across a thin wall); ``footprint`` gives the same area as an exact geometry. The
coverage candidates (``planning.coverage``) and every score of a tour or a sweep read it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely.geometry import LineString, Point
from shapely.geometry.base import BaseGeometry

from orange_plan.errors import InputError
from orange_plan.limits import MAX_COVERAGE_CELLS, MAX_COVERAGE_LATTICE_POINTS, smallest_radius_m

HEX_AREA_PER_R2 = 1.5 * math.sqrt(3.0)
"""Area of one viewpoint lattice cell over r^2 (spacing r sqrt 3 by rows 1.5 r apart)."""

CELLS_PER_RADIUS = 3
"""Default cell side is r / 3: a disc of radius r then holds ~28 cells (area error ~ 5 %)."""

LATTICE_PER_CELL = 8
"""The dense lattice over the free space's bounding box may hold this many times max_cells."""


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
