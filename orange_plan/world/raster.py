"""Elevation rasters (GeoTIFF or ESRI ASCII grid) in the map's metric frame."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from orange_plan.errors import MapError
from orange_plan.files import file_problem
from orange_plan.limits import MAX_ELEVATION_CELLS


@dataclass(frozen=True)
class ElevationRaster:
    """Elevations at cell centres of a north-up grid.

    Attributes
    ----------
    z_m : elevation, shape (rows, cols), row 0 = southernmost [m]
    x0_m, y0_m : coordinates of the centre of cell (row 0, col 0) [m]
    cell_m : cell size [m]
    """

    z_m: np.ndarray
    x0_m: float
    y0_m: float
    cell_m: float

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        """Outer extent (xmin, ymin, xmax, ymax) of the cells [m]."""
        rows, cols = self.z_m.shape
        h = self.cell_m / 2
        return (self.x0_m - h, self.y0_m - h,
                self.x0_m + (cols - 1) * self.cell_m + h, self.y0_m + (rows - 1) * self.cell_m + h)

    def elevation_at(self, x_m, y_m) -> np.ndarray:
        """Bilinear elevation between cell centres, constant over the outer half cell [m].

        Accepts arrays of any (broadcastable) shape and returns that shape.
        """
        x, y = np.broadcast_arrays(np.asarray(x_m, float), np.asarray(y_m, float))
        rows, cols = self.z_m.shape
        fx = np.clip((x - self.x0_m) / self.cell_m, 0.0, cols - 1)
        fy = np.clip((y - self.y0_m) / self.cell_m, 0.0, rows - 1)
        i0 = np.minimum(np.floor(fy).astype(int), max(rows - 2, 0))
        j0 = np.minimum(np.floor(fx).astype(int), max(cols - 2, 0))
        i1, j1 = np.minimum(i0 + 1, rows - 1), np.minimum(j0 + 1, cols - 1)
        ty, tx = fy - i0, fx - j0
        z = self.z_m
        return ((z[i0, j0] * (1 - tx) + z[i0, j1] * tx) * (1 - ty)
                + (z[i1, j0] * (1 - tx) + z[i1, j1] * tx) * ty)


def load_elevation(path: Path) -> ElevationRaster:
    """Read a GeoTIFF or ESRI ASCII grid (.asc) with rasterio.

    Raises
    ------
    MapError
        If the file is missing, unreadable, rotated, larger than
        ``limits.MAX_ELEVATION_CELLS`` cells, or holds no-data cells.
    """
    problem = file_problem(path, path.name, "elevation raster")
    if problem:
        raise MapError(f"elevation raster {problem}")
    import rasterio

    try:
        with rasterio.open(path) as src:
            _check_size(src.height, src.width, path)  # before reading: the header is enough
            band = src.read(1, masked=True).astype(float)
            t = src.transform
    except rasterio.errors.RasterioError as exc:
        raise MapError(f"elevation raster '{path.name}' could not be read ({exc})") from None
    if t.b != 0 or t.d != 0 or not np.isclose(abs(t.a), abs(t.e)):
        raise MapError(f"elevation raster '{path.name}' must be north-up with square cells")
    if np.ma.is_masked(band) and band.mask.any():
        raise MapError(f"elevation raster '{path.name}' has {int(band.mask.sum())} no-data cells")
    z = np.asarray(band.filled(np.nan))
    cell = abs(t.a)
    # rasterio's transform maps the outer corner; row 0 of the file is the north edge.
    x0 = t.c + cell / 2
    if t.e < 0:
        z = z[::-1]
        y0 = t.f + t.e * band.shape[0] + cell / 2
    else:
        y0 = t.f + cell / 2
    if not np.all(np.isfinite(z)):
        raise MapError(f"elevation raster '{path.name}' holds non-finite values")
    return ElevationRaster(np.ascontiguousarray(z), float(x0), float(y0), float(cell))


def _check_size(rows: int, cols: int, path: Path) -> None:
    """Refuse a raster with more than ``MAX_ELEVATION_CELLS`` cells before reading it."""
    if rows * cols > MAX_ELEVATION_CELLS:
        raise MapError(f"elevation raster '{path.name}' has {rows} x {cols} cells, more than "
                       f"the limit of {MAX_ELEVATION_CELLS:,}: resample it to coarser cells")
