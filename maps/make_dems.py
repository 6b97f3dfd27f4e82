"""Regenerate the example elevation rasters next to this file.

    python maps/make_dems.py

Writes, deterministically (no randomness), in the maps' local metric frame (x east, y north):

- ``lab_ramp_dem.asc``: ESRI ASCII grid for ``lab_ramp.geojson`` (8 m x 6 m lab). Flat floor at
  z = 0 for x <= 2.5 m, a 4 degree ramp from x = 2.5 m to x = 5.5 m (rise 0.21 m), then a flat
  platform. 0.25 m cells, 0.5 m margin around the boundary.
- ``hilly_campus_dem.tif``: float32 GeoTIFF for ``hilly_campus.geojson`` (800 m x 800 m).
  Flat ground at z = 0 with two Gaussian hills: a 45 m hill (sigma 100 m, steepest grade about
  27 %) on the straight line between the depot (60, 400) and the east side of the campus, and a
  30 m hill (sigma 80 m) to the north-east. 5 m cells, 20 m (4 cells) margin around the boundary.
  Sized so that, for ``scenarios/kiwibot_campus.toml`` under the reference model (climbing costs
  m g dz / Omega, nothing is recovered downhill), driving from the depot to (740, 400) round the
  south of the big hill costs about a third less energy than the straight walk over its top.

Raster values are elevations at cell centres (SPEC section 7). Needs numpy and rasterio.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent

# lab_ramp: grid and ramp geometry [m]
LAB_XLL_M, LAB_YLL_M = -0.5, -0.5  # outer (lower-left) corner of the grid
LAB_CELL_M = 0.25
LAB_NCOLS, LAB_NROWS = 36, 28  # covers x -0.5..8.5, y -0.5..6.5
RAMP_X0_M, RAMP_X1_M = 2.5, 5.5
RAMP_ANGLE_DEG = 4.0

# hilly_campus: grid and hills [m]
CAMPUS_XMIN_M, CAMPUS_YMAX_M = -20.0, 820.0  # outer north-west corner of the grid
CAMPUS_CELL_M = 5.0
CAMPUS_N = 168  # 168 cells x 5 m = 840 m: covers -20..820 in x and y
HILLS = (
    # (x_m, y_m, height_m, sigma_m)
    (400.0, 410.0, 45.0, 100.0),  # "observatory hill", between the depot and the east side
    (620.0, 660.0, 30.0, 80.0),   # "north knoll"
)


def lab_ramp_elevation(x_m: np.ndarray) -> np.ndarray:
    """Floor height of the lab at easting ``x_m`` [m]: flat, 4 degree ramp, flat platform."""
    rise_m = (RAMP_X1_M - RAMP_X0_M) * math.tan(math.radians(RAMP_ANGLE_DEG))
    frac = np.clip((x_m - RAMP_X0_M) / (RAMP_X1_M - RAMP_X0_M), 0.0, 1.0)
    return rise_m * frac


def campus_elevation(x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """Ground height of the campus [m]: a sum of Gaussian hills on flat ground at z = 0."""
    z = np.zeros(np.broadcast(x_m, y_m).shape)
    for hx, hy, h, s in HILLS:
        z += h * np.exp(-((x_m - hx) ** 2 + (y_m - hy) ** 2) / (2.0 * s * s))
    return z


def write_lab_ramp(path: Path) -> None:
    """ESRI ASCII grid; rows are written north to south."""
    xc = LAB_XLL_M + LAB_CELL_M * (np.arange(LAB_NCOLS) + 0.5)
    z_row = lab_ramp_elevation(xc)  # the ramp runs east-west: every row is the same
    lines = [
        f"ncols {LAB_NCOLS}",
        f"nrows {LAB_NROWS}",
        f"xllcorner {LAB_XLL_M}",
        f"yllcorner {LAB_YLL_M}",
        f"cellsize {LAB_CELL_M}",
        "NODATA_value -9999",
    ]
    row_text = " ".join(f"{v:.4f}" for v in z_row)
    lines += [row_text] * LAB_NROWS
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


def write_hilly_campus(path: Path) -> None:
    """Float32 north-up GeoTIFF without a CRS (local metric frame)."""
    import rasterio
    from rasterio.transform import from_origin

    centres = (np.arange(CAMPUS_N) + 0.5) * CAMPUS_CELL_M
    xc = CAMPUS_XMIN_M + centres
    yc = CAMPUS_YMAX_M - centres  # row 0 is the northern edge
    z = campus_elevation(xc[None, :], yc[:, None]).astype(np.float32)
    profile = {
        "driver": "GTiff",
        "width": CAMPUS_N,
        "height": CAMPUS_N,
        "count": 1,
        "dtype": "float32",
        "transform": from_origin(CAMPUS_XMIN_M, CAMPUS_YMAX_M, CAMPUS_CELL_M, CAMPUS_CELL_M),
        "compress": "deflate",
        "predictor": 3,
    }
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(z, 1)


def main() -> None:
    write_lab_ramp(HERE / "lab_ramp_dem.asc")
    write_hilly_campus(HERE / "hilly_campus_dem.tif")


if __name__ == "__main__":
    main()
