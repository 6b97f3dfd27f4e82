"""Terrain rasters built once per map: occupancy, rolling coefficient and surface code.

The exact shapely queries of ``World`` cost microseconds per point; a roadmap of thousands of
vertices needs tens of millions of terrain look-ups. These grids are computed once with
vectorised ``shapely.contains_xy`` at cell centres and read by nearest-cell indexing, which is
what the planner's inner loops (OMPL validity callbacks, roadmap edge weights) use. Anything
reported to a user is re-checked or re-evaluated with the exact ``World`` queries.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from orange_plan.errors import InputError
from orange_plan.limits import MAX_RASTER_CELLS

MAX_CELLS = MAX_RASTER_CELLS
"""Largest grid built by default (``limits.MAX_RASTER_CELLS``)."""


@dataclass(frozen=True)
class TerrainRasters:
    """Nearest-cell grids over the boundary's bounding box (row 0 = south, col 0 = west).

    Attributes
    ----------
    x0_m, y0_m : centre of cell (0, 0) [m]
    cell_m : cell size [m]
    free : True where the cell centre is in free space (boundary minus keep-out)
    crr : rolling coefficient at the cell centre [-]
    surface_code : index into ``map.surface_names``, -1 for default ground
    free_rows : ``free`` as a list of lists, for scalar look-ups in OMPL callbacks
    """

    x0_m: float
    y0_m: float
    cell_m: float
    free: np.ndarray
    crr: np.ndarray
    surface_code: np.ndarray
    free_rows: list

    @property
    def shape(self) -> tuple[int, int]:
        return self.free.shape

    def index(self, x_m, y_m) -> tuple[np.ndarray, np.ndarray]:
        """(row, col) of the cell nearest to each point, clipped to the grid."""
        rows, cols = self.free.shape
        i = np.clip(np.rint((np.asarray(y_m, float) - self.y0_m) / self.cell_m), 0, rows - 1)
        j = np.clip(np.rint((np.asarray(x_m, float) - self.x0_m) / self.cell_m), 0, cols - 1)
        return i.astype(np.intp), j.astype(np.intp)

    def crr_at(self, x_m, y_m) -> np.ndarray:
        """Rolling coefficient of the nearest cell [-] (same contract as ``World.crr_at``)."""
        return self.crr[self.index(x_m, y_m)]

    def surface_code_at(self, x_m, y_m) -> np.ndarray:
        """Surface code of the nearest cell (same contract as ``World.surface_code_at``)."""
        return self.surface_code[self.index(x_m, y_m)]

    def is_free(self, x_m, y_m) -> np.ndarray:
        """Occupancy of the nearest cell (approximate: exact tests use ``World.is_free``)."""
        return self.free[self.index(x_m, y_m)]

    def segments_free(self, start_xy, end_xy) -> np.ndarray:
        """Approximate collision test of straight segments, sampled every cell (n,)."""
        a = np.atleast_2d(np.asarray(start_xy, float))
        b = np.atleast_2d(np.asarray(end_xy, float))
        n_sub = np.maximum(1, np.ceil(np.hypot(*(b - a).T) / self.cell_m).astype(int))
        seg = np.repeat(np.arange(len(a)), n_sub + 1)
        k = np.arange(seg.size) - np.repeat(np.cumsum(n_sub + 1) - (n_sub + 1), n_sub + 1)
        t = (k / n_sub[seg])[:, None]
        p = a[seg] + (b - a)[seg] * t
        ok = self.is_free(p[:, 0], p[:, 1])
        return np.bincount(seg, weights=~ok, minlength=len(a)) == 0


def build_rasters(world, cell_m: float | None = None, max_cells: int = MAX_CELLS) -> TerrainRasters:
    """Rasterise a World's occupancy, rolling coefficient and surface code once.

    Parameters
    ----------
    world : the World (map + environment)
    cell_m : cell size [m]; default: 1/800 of the longer side of the boundary's bounding box,
        at most half an elevation cell, and coarse enough for ``max_cells``
    max_cells : cap on rows x cols

    Raises
    ------
    InputError
        If ``cell_m`` is not positive or would exceed ``max_cells``.
    """
    xmin, ymin, xmax, ymax = world.map.boundary.bounds
    span = max(xmax - xmin, ymax - ymin)
    if cell_m is None:
        cell_m = span / 800.0
        if world.map.elevation is not None:
            cell_m = min(cell_m, world.map.elevation.cell_m / 2)
        cell_m = max(cell_m, np.sqrt((xmax - xmin) * (ymax - ymin) / max_cells))
    if not cell_m > 0:
        raise InputError(f"raster cell_m = {cell_m!r} must be > 0")
    cols = int(np.ceil((xmax - xmin) / cell_m)) + 1
    rows = int(np.ceil((ymax - ymin) / cell_m)) + 1
    if rows * cols > max_cells * 1.01:
        raise InputError(f"raster of {rows} x {cols} cells at cell_m = {cell_m:g} m is too large")
    x = xmin + cell_m * np.arange(cols)
    y = ymin + cell_m * np.arange(rows)
    gx, gy = np.meshgrid(x, y)
    shapely.prepare(world.map.boundary)
    free = shapely.intersects_xy(world.map.boundary, gx, gy)
    keep_out = world.map.keep_out
    if not keep_out.is_empty:
        shapely.prepare(keep_out)
        free &= ~shapely.intersects_xy(keep_out, gx, gy)
    return TerrainRasters(
        x0_m=float(xmin),
        y0_m=float(ymin),
        cell_m=float(cell_m),
        free=free,
        crr=world.crr_at(gx, gy),
        surface_code=world.surface_code_at(gx, gy),
        free_rows=free.tolist(),
    )
