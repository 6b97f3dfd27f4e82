"""Elevation rasters: cell-centre values, bilinear between centres, flat outer half cell."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import write_asc

from orange_plan.errors import MapError
from orange_plan.world.raster import ElevationRaster, load_elevation

# 2 rows x 3 cols, written north row first: south row z = 0, 1, 2; north row z = 10, 11, 12
NORTH_FIRST = [[10.0, 11.0, 12.0], [0.0, 1.0, 2.0]]


@pytest.mark.parametrize(("corner", "origin"), [(True, 0.0), (False, 1.0)],
                         ids=["xllcorner", "xllcenter"])
def test_asc_grid_geometry(tmp_path, corner, origin):
    # 2 m cells: xllcorner 0 puts the first centre at (1, 1); xllcenter 1 says so directly
    r = load_elevation(write_asc(tmp_path / "g.asc", NORTH_FIRST, 2.0, origin, origin, corner))
    assert (r.x0_m, r.y0_m, r.cell_m) == (1.0, 1.0, 2.0)
    assert r.bounds_m == (0.0, 0.0, 6.0, 4.0)
    np.testing.assert_array_equal(r.z_m, [[0, 1, 2], [10, 11, 12]])  # row 0 = south


def test_bilinear_hand_value():
    r = ElevationRaster(np.array([[0.0, 1.0, 2.0], [10.0, 11.0, 12.0]]), 1.0, 1.0, 2.0)
    # at cell centres: the cell values
    assert float(r.elevation_at(3.0, 3.0)) == 11.0
    # (2, 2): tx = 0.5 between centres x = 1 and 3, ty = 0.5 between y = 1 and 3
    # (0 + 1 + 10 + 11) / 4 = 5.5
    assert float(r.elevation_at(2.0, 2.0)) == pytest.approx(5.5)
    # (4.5, 1.5): tx = 0.75 between 1 and 2 (south: 1.75, north: 11.75), ty = 0.25
    # 1.75 * 0.75 + 11.75 * 0.25 = 4.25
    assert float(r.elevation_at(4.5, 1.5)) == pytest.approx(4.25)


def test_constant_over_outer_half_cell():
    r = ElevationRaster(np.array([[0.0, 1.0, 2.0], [10.0, 11.0, 12.0]]), 1.0, 1.0, 2.0)
    # west of the first centre (x < 1) and south of y = 1: the corner cell value
    np.testing.assert_allclose(r.elevation_at([0.0, 0.5, 1.0], [0.0, 0.2, 1.0]), [0.0, 0.0, 0.0])
    # east edge x in [5, 6] keeps column 2; north edge y in [3, 4] keeps row 1
    np.testing.assert_allclose(r.elevation_at([5.0, 5.5, 6.0], 3.5), [12.0, 12.0, 12.0])
    # along the west edge it still interpolates in y: (0.3, 2) -> (0 + 10) / 2
    assert float(r.elevation_at(0.3, 2.0)) == pytest.approx(5.0)


def test_elevation_shapes():
    r = ElevationRaster(np.arange(12.0).reshape(3, 4), 0.0, 0.0, 1.0)
    assert np.ndim(r.elevation_at(1.2, 0.7)) == 0
    assert r.elevation_at(np.zeros(5), np.linspace(0, 2, 5)).shape == (5,)
    grid = r.elevation_at(np.linspace(0, 3, 4)[:, None], np.linspace(0, 2, 3))
    assert grid.shape == (4, 3)
    # z = 4 row + col on this grid, and bilinear reproduces a plane exactly
    np.testing.assert_allclose(grid, np.linspace(0, 3, 4)[:, None] + 4 * np.linspace(0, 2, 3))


def test_geotiff_north_up(tmp_path):
    import rasterio
    from rasterio.transform import Affine

    path = tmp_path / "dem.tif"
    z = np.array(NORTH_FIRST, dtype="float32")
    with rasterio.open(path, "w", driver="GTiff", height=2, width=3, count=1, dtype="float32",
                       transform=Affine(2.0, 0.0, 10.0, 0.0, -2.0, 24.0)) as dst:
        dst.write(z, 1)
    r = load_elevation(path)
    # outer north-west corner (10, 24), 2 m cells: south-west centre at (11, 21)
    assert (r.x0_m, r.y0_m) == (11.0, 21.0)
    assert float(r.elevation_at(11.0, 21.0)) == 0.0 and float(r.elevation_at(15.0, 23.0)) == 12.0


def test_bad_rasters(tmp_path):
    with pytest.raises(MapError, match=r"elevation raster 'none\.asc' not found"):
        load_elevation(tmp_path / "none.asc")
    write_asc(tmp_path / "holes.asc", [[0.0, -9999.0], [1.0, 2.0]], 1.0, 0.0, 0.0)
    with pytest.raises(MapError, match="has 1 no-data cells"):
        load_elevation(tmp_path / "holes.asc")
    (tmp_path / "junk.asc").write_text("not a raster\n", encoding="utf-8")
    with pytest.raises(MapError, match=r"'junk\.asc' could not be read"):
        load_elevation(tmp_path / "junk.asc")
