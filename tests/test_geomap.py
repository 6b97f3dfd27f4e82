"""Map GeoJSON loading and validation (docs/formats.md, map)."""

from __future__ import annotations

import pytest
from conftest import BOUNDARY, base_features, feature, write_asc, write_map

from orange_plan.errors import MapError
from orange_plan.world.geomap import load_map


def test_loads_valid_map(map_path):
    m = load_map(map_path)
    assert m.boundary.area == 200.0
    assert m.home_xy_m == (2.0, 5.0)
    assert m.surface_names == ("grass",) and m.surfaces[0].crr == 0.1
    assert m.keep_out.area == 4.0 and m.free_space.area == 196.0
    assert m.default_surface is None and m.elevation is None


def test_default_surface_and_no_go(tmp_path):
    feats = [*base_features(), feature("no_go", "Polygon", [[[12, 1], [14, 1], [14, 3], [12, 1]]])]
    m = load_map(write_map(tmp_path, feats, default_surface={"name": "asphalt", "crr": 0.015}))
    assert m.default_surface == ("asphalt", 0.015)
    assert len(m.no_go) == 1 and m.keep_out.area == pytest.approx(4.0 + 2.0)


def bow_tie():
    return feature("boundary", "Polygon", [[[0, 0], [10, 10], [10, 0], [0, 10], [0, 0]]])


@pytest.mark.parametrize(
    ("features", "top", "match"),
    [
        ([], {}, r"empty map \(no features"),
        ([bow_tie()], {}, r"feature 0 \(boundary\) is self-intersecting"),
        ([feature("boundary", "Polygon", [])], {}, r"feature 0 \(boundary\) is empty"),
        ([feature("home", "Point", [1, 1])], {}, r"needs exactly one boundary feature, found 0"),
        ([feature("boundary", "Polygon", [BOUNDARY])] * 2, {}, r"exactly one boundary .* found 2"),
        ([*base_features()[:3], feature("home", "Point", [5.0, 8.0])], {},
         r"feature 3 \(home\) lies inside an obstacle"),
        ([*base_features()[:3], feature("home", "Point", [50.0, 8.0])], {},
         r"feature 3 \(home\) lies outside the boundary"),
        ([*base_features(), feature("obstacel", "Polygon", [[[1, 1], [2, 1], [2, 2], [1, 1]]])], {},
         r"feature 4 has unknown kind 'obstacel'.*did you mean 'obstacle'"),
        ([feature("boundary", "Polygon", [BOUNDARY]),
          feature("surface", "Polygon", [[[1, 1], [2, 1], [2, 2], [1, 1]]], name="ice", crr=1.5)],
         {}, r"feature 1 \(surface 'ice'\) has crr = 1.5 outside \[0, 1\]"),
        ([feature("boundary", "Polygon", [BOUNDARY]),
          feature("surface", "Polygon", [[[1, 1], [2, 1], [2, 2], [1, 1]]], crr=0.1)],
         {}, r"feature 1 \(surface\) needs a 'name'"),
        ([feature("boundary", "Polygon", [BOUNDARY]), feature("obstacle", "Point", [1, 1])], {},
         r"feature 1 \(obstacle\) must be a Polygon"),
        (None, {"default_surface": {"name": "mud", "crr": -0.2}}, r"default_surface has crr = -0.2"),
        (None, {"elevation": "missing_dem.asc"}, r"elevation raster 'missing_dem.asc' not found"),
        (None, {"elevaton": "dem.asc"},
         r"unknown top-level member 'elevaton' \(did you mean 'elevation'\?\)"),
    ],
)
def test_bad_maps(tmp_path, features, top, match):
    path = write_map(tmp_path, features, **top)
    with pytest.raises(MapError, match=match) as info:
        load_map(path)
    assert "\n" not in str(info.value)


def test_raster_not_covering_the_boundary(tmp_path):
    write_asc(tmp_path / "small.asc", [[0.0] * 4] * 4, 1.0, 0.0, 0.0)  # covers 0..4 m only
    with pytest.raises(MapError, match=r"raster 'small.asc' covers x 0..4, y 0..4 m but the "
                                        r"boundary spans x 0..20, y 0..10 m"):
        load_map(write_map(tmp_path, elevation="small.asc"))


def test_not_json_and_not_a_collection(tmp_path):
    bad = tmp_path / "bad.geojson"
    bad.write_text("{not json", encoding="utf-8")
    with pytest.raises(MapError, match="not a valid GeoJSON/JSON file"):
        load_map(bad)
    bad.write_text('{"type": "Feature"}', encoding="utf-8")
    with pytest.raises(MapError, match="must be a GeoJSON FeatureCollection"):
        load_map(bad)
    with pytest.raises(MapError, match="map file not found"):
        load_map(tmp_path / "absent.geojson")


def test_optional_origin_member_is_accepted_and_checked(tmp_path):
    """The map's origin: the WGS84 point at x = y = 0, a foreign member of the FeatureCollection."""
    m = load_map(write_map(tmp_path, origin={"lat_deg": 48.137, "lon_deg": 11.575, "alt_m": 520.0}))
    assert (m.origin.lat_deg, m.origin.lon_deg, m.origin.alt_m) == (48.137, 11.575, 520.0)
    assert load_map(write_map(tmp_path, name="plain.geojson")).origin is None
    with pytest.raises(MapError, match=r"origin has unknown member 'lat' \(did you mean"):
        load_map(write_map(tmp_path, name="bad.geojson", origin={"lat": 1.0}))
