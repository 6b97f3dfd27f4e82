"""Map GeoJSON -> a validated, frozen Map."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Point, Polygon, shape
from shapely.validation import explain_validity

from orange_plan.errors import MapError, close_match_hint
from orange_plan.files import read_json, require_file
from orange_plan.world.raster import ElevationRaster, load_elevation

KINDS = {"boundary", "obstacle", "no_go", "surface", "home"}
TOP_LEVEL_KEYS = {"type", "features", "default_surface", "elevation", "origin", "name", "crs",
                  "bbox"}
ORIGIN_RANGES = {"lat_deg": (-90.0, 90.0), "lon_deg": (-180.0, 180.0), "alt_m": (-1e5, 1e5)}
"""The members of ``origin`` and their allowed ranges (alt_m: metres above the WGS84
ellipsoid, from the Dead Sea shore to well above any flight)."""

MAX_COORD_M = 1e7
"""Largest |x| or |y| [m]: a local tangent plane is meaningless 10,000 km from its origin,
and larger numbers (1e300) made the planner's sub-steps run for minutes."""

MIN_EXTENT_M = 1.0
"""A workspace smaller than this in both directions is refused: it is almost certainly
longitude/latitude in degrees, not metres."""

GEOGRAPHIC_CRS = ("4326", "crs84", "4269", "4258", "wgs 84", "wgs84")
"""Markers of a longitude/latitude ``crs`` member (EPSG:4326, OGC CRS84, NAD83, ETRS89)."""


@dataclass(frozen=True)
class Origin:
    """The WGS84 point at x = y = 0 of the map's local east-north-up frame.

    Attributes
    ----------
    lat_deg, lon_deg : latitude and longitude [deg]
    alt_m : altitude [m]
    """

    lat_deg: float
    lon_deg: float
    alt_m: float


@dataclass(frozen=True)
class Surface:
    """A surface polygon with its rolling coefficient (later surfaces win on overlap)."""

    name: str
    crr: float
    polygon: Polygon | MultiPolygon


@dataclass(frozen=True)
class Map:
    """A validated map in a local metric frame (x east, y north) [m].

    Attributes
    ----------
    boundary : the workspace
    keep_out : union of obstacles and no-go zones (empty polygon if none)
    obstacles, no_go : the individual keep-out polygons
    surfaces : surfaces in file order (later ones win)
    home_xy_m : the map's home point, or None
    default_surface : (name, crr) or None
    elevation : raster, or None for flat ground at z = 0
    path : the file it came from
    origin : the WGS84 point at x = y = 0, or None (exports/imports in lat/lon are refused)
    version : 0 as loaded, one more after each update (a mission's new obstacles): what was
        computed for one version (a roadmap, a plan) is known stale by comparing versions
    """

    boundary: Polygon
    obstacles: tuple
    no_go: tuple
    surfaces: tuple[Surface, ...]
    home_xy_m: tuple[float, float] | None
    default_surface: tuple[str, float] | None
    elevation: ElevationRaster | None
    path: Path
    origin: Origin | None = None
    version: int = 0

    @property
    def keep_out(self):
        return shapely.union_all([*self.obstacles, *self.no_go])

    @property
    def free_space(self):
        """Boundary minus keep-out zones."""
        return self.boundary.difference(self.keep_out)

    @property
    def surface_names(self) -> tuple[str, ...]:
        """Distinct surface names in order of first appearance."""
        return tuple(dict.fromkeys(s.name for s in self.surfaces))


def load_map(path: str | Path) -> Map:
    """Read and validate a map GeoJSON file.

    Raises
    ------
    MapError
        One line naming the file, the feature index and the problem. Nothing is repaired.
    """
    path = Path(path)
    require_file(path, "map", MapError)
    data = read_json(path, "GeoJSON/JSON", MapError)
    if not isinstance(data, dict) or data.get("type") != "FeatureCollection":
        raise MapError(f"{path}: must be a GeoJSON FeatureCollection")
    for key in data:
        if key not in TOP_LEVEL_KEYS:  # a misspelt "elevation" must not silently mean flat ground
            raise MapError(
                f"{path}: unknown top-level member '{key}'" + close_match_hint(key, TOP_LEVEL_KEYS)
            )
    _check_crs(data.get("crs"), path)
    origin = _origin(data.get("origin"), path)
    features = data.get("features")
    if not isinstance(features, list) or not features:
        raise MapError(f"{path}: empty map (no features; need at least a boundary)")
    parts: dict[str, list] = {k: [] for k in KINDS}
    for i, feature in enumerate(features):
        kind, geom, props = _feature(feature, i, path)
        parts[kind].append((i, geom, props))

    boundary = _boundary(parts["boundary"], path)
    _check_extent(boundary, parts["boundary"][0][0], path)
    obstacles, no_go = (tuple(keep_out_polygon(g, f"{path}: feature {i} ({kind})", boundary)
                              for i, g, _ in parts[kind]) for kind in ("obstacle", "no_go"))
    surfaces = tuple(_surface(i, g, p, path) for i, g, p in parts["surface"])
    home = _home(parts["home"], boundary, obstacles + no_go, path)
    default_surface = _default_surface(data.get("default_surface"), path)
    elevation = None
    if "elevation" in data:
        elevation = load_elevation(_raster_path(data["elevation"], path))
        _check_covers(elevation, boundary, data["elevation"], path)
    return Map(boundary, obstacles, no_go, surfaces, home, default_surface, elevation, path,
               origin)


def _raster_path(name, path: Path) -> Path:
    """The elevation raster's path, confined to the map's folder (and its subfolders)."""
    if not isinstance(name, str) or not name:
        raise MapError(f"{path}: 'elevation' must be a raster file name")
    folder = path.parent.resolve()
    target = (folder / name).resolve()
    if Path(name).is_absolute() or not target.is_relative_to(folder):
        raise MapError(f"{path}: 'elevation' = {name!r} must be a file in the map's folder "
                       f"({folder}) or below it, given relative to the map")
    return target


def _check_crs(crs, path: Path) -> None:
    """Refuse a longitude/latitude ``crs``: the map must be in a local metric frame."""
    if crs is None:
        return
    text = json.dumps(crs).lower().replace("_", " ")
    if any(marker in text for marker in GEOGRAPHIC_CRS):
        raise MapError(f"{path}: 'crs' {json.dumps(crs)} is longitude/latitude; orange-plan "
                       "needs a local metric frame (x east, y north, metres): project the map "
                       "and give its WGS84 anchor as 'origin'")


def _origin(value, path: Path) -> Origin | None:
    if value is None:
        return None
    if not isinstance(value, dict):
        raise MapError(f"{path}: 'origin' must be {{\"lat_deg\": ..., \"lon_deg\": ..., "
                       f"\"alt_m\": ...}}, got {value!r}")
    for key in value:
        if key not in ORIGIN_RANGES:
            raise MapError(f"{path}: origin has unknown member '{key}'"
                           + close_match_hint(key, ORIGIN_RANGES))
    numbers = {}
    for key, (lo, hi) in ORIGIN_RANGES.items():
        v = value.get(key)
        if v is None:
            raise MapError(f"{path}: origin needs '{key}'")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
            raise MapError(f"{path}: origin {key} = {v!r} must be a number in [{lo:g}, {hi:g}]")
        numbers[key] = float(v)
    return Origin(**numbers)


def _check_extent(boundary: Polygon, i: int, path: Path) -> None:
    x0, y0, x1, y1 = boundary.bounds
    if max(abs(x0), abs(y0), abs(x1), abs(y1)) > MAX_COORD_M:
        raise MapError(f"{path}: feature {i} (boundary) has coordinates beyond {MAX_COORD_M:g} m "
                       "from the origin; the map must be in a local metric frame")
    if max(x1 - x0, y1 - y0) < MIN_EXTENT_M:
        raise MapError(f"{path}: feature {i} (boundary) spans only {x1 - x0:g} x {y1 - y0:g} m; "
                       "are these longitude/latitude degrees? orange-plan needs metres "
                       "(x east, y north)")


def _feature(feature, i: int, path: Path):
    if not isinstance(feature, dict) or feature.get("type") != "Feature":
        raise MapError(f"{path}: feature {i} is not a GeoJSON Feature")
    props = feature.get("properties") or {}
    kind = props.get("kind")
    if kind not in KINDS:
        raise MapError(
            f"{path}: feature {i} has unknown kind {kind!r} (allowed: {', '.join(sorted(KINDS))})"
            + close_match_hint(str(kind), KINDS)
        )
    return kind, map_geometry(feature.get("geometry"), f"{path}: feature {i} ({kind})"), props


def keep_out_polygon(geometry, what: str, boundary: Polygon | None = None):
    """An obstacle or no-go zone, checked by the rules of a map file.

    The one check for keep-out zones: a map file's obstacles and no-go zones and those a
    running mission receives as a map update (``MissionSession.update_map``, the service's
    map endpoint) pass the same rules.

    Parameters
    ----------
    geometry : a GeoJSON geometry (dict), a shapely geometry, or coordinates: one ring
        ``[[x, y], ...]`` or a Polygon's rings ``[[[x, y], ...], ...]`` [m]
    what : how an error names it, e.g. ``"map update: obstacles[0]"``
    boundary : the map's boundary, which the zone must overlap; None: not checked

    Returns
    -------
    The Polygon or MultiPolygon, as given (nothing is repaired).

    Raises
    ------
    MapError
        One line naming ``what``: malformed, a ring not closed, a coordinate not finite or
        beyond ``MAX_COORD_M``, not a Polygon/MultiPolygon, empty, invalid (self-
        intersecting), or entirely outside the boundary.
    """
    geom = _polygonal(map_geometry(geometry, what), what)
    if boundary is not None and not boundary.intersects(geom):
        raise MapError(f"{what} lies entirely outside the map's boundary")
    return geom


def map_geometry(geometry, what: str):
    """A shapely geometry from GeoJSON, shapely or coordinate rings, in a metric frame.

    Raises
    ------
    MapError
        Malformed geometry, a GeoJSON ring that does not end where it starts (shapely would
        close it silently), or a coordinate that is not finite or lies beyond
        ``MAX_COORD_M`` (one line naming ``what``).
    """
    if hasattr(geometry, "geom_type"):
        _check_coordinates(shapely.get_coordinates(geometry), what)
        return geometry
    geometry = _as_geojson(geometry, what)
    _check_coordinates(np.fromiter(_numbers(geometry.get("coordinates")), float), what)
    _check_rings_closed(geometry, what)
    try:
        return shape(geometry)
    except Exception as exc:  # noqa: BLE001 - shapely raises several types here
        raise MapError(f"{what} has malformed geometry ({exc})") from None


def _check_coordinates(numbers: np.ndarray, what: str) -> None:
    if not (np.all(np.isfinite(numbers)) and np.all(np.abs(numbers) <= MAX_COORD_M)):
        raise MapError(f"{what} has a coordinate that is not finite or lies beyond "
                       f"{MAX_COORD_M:g} m from the origin")


def _numbers(coordinates):
    """Every number in nested GeoJSON coordinates (anything else is left to shapely)."""
    if isinstance(coordinates, (int, float)) and not isinstance(coordinates, bool):
        yield float(coordinates)
    elif isinstance(coordinates, (list, tuple)):
        for item in coordinates:
            yield from _numbers(item)


def _as_geojson(geometry, what: str):
    """A GeoJSON geometry as given; bare coordinates (one ring, or a Polygon's rings) as a
    GeoJSON Polygon."""
    if isinstance(geometry, dict):
        return geometry
    if not isinstance(geometry, (list, tuple, np.ndarray)):
        raise MapError(f"{what} is not a GeoJSON geometry nor polygon coordinates, got "
                       f"{type(geometry).__name__}")
    try:
        rings = np.asarray(geometry, float)
    except (TypeError, ValueError):  # numpy's text (ragged shapes) says nothing to a user
        raise MapError(f"{what} is not a polygon: give a ring [[x, y], ...] or a list of "
                       "rings, every vertex two numbers") from None
    if rings.ndim not in (2, 3) or rings.shape[-1] != 2:
        raise MapError(f"{what} is not a polygon: coordinates must be a ring [[x, y], ...] or "
                       f"a list of rings, got an array of shape {rings.shape}")
    return {"type": "Polygon", "coordinates": (rings[None] if rings.ndim == 2 else rings).tolist()}


def _check_rings_closed(geometry, what: str) -> None:
    """GeoJSON rings must end where they start; shapely would close them silently."""
    if not isinstance(geometry, dict):
        return
    kind, coords = geometry.get("type"), geometry.get("coordinates")
    polygons = [coords] if kind == "Polygon" else coords if kind == "MultiPolygon" else []
    for polygon in polygons or []:
        for j, ring in enumerate(polygon if isinstance(polygon, list) else []):
            if isinstance(ring, list) and len(ring) >= 2 and ring[0] != ring[-1]:
                raise MapError(f"{what}: ring {j} is not closed (its first position "
                               f"{ring[0]} differs from its last {ring[-1]}); nothing is repaired")


def _polygonal(geom, what: str):
    """A non-empty, valid Polygon or MultiPolygon (as given: nothing is repaired)."""
    if not isinstance(geom, (Polygon, MultiPolygon)):
        raise MapError(f"{what} must be a Polygon or MultiPolygon, got a {geom.geom_type}")
    if geom.is_empty:
        raise MapError(f"{what} is empty")
    if not geom.is_valid:
        raise MapError(f"{what} is invalid: {explain_validity(geom)}")
    return geom


def _boundary(found, path: Path) -> Polygon:
    if len(found) != 1:
        raise MapError(f"{path}: needs exactly one boundary feature, found {len(found)}")
    i, geom, _ = found[0]
    if not isinstance(geom, Polygon):
        raise MapError(f"{path}: feature {i} (boundary) must be a Polygon")
    # Validity first: a bow-tie's signed lobes cancel to zero area, yet it is self-intersecting.
    if not geom.is_empty and not geom.is_valid:
        raise MapError(
            f"{path}: feature {i} (boundary) is self-intersecting or invalid: {explain_validity(geom)}"
        )
    if geom.is_empty or geom.area <= 0:
        raise MapError(f"{path}: feature {i} (boundary) is empty")
    return geom


def _surface(i: int, geom, props, path: Path) -> Surface:
    geom = _polygonal(geom, f"{path}: feature {i} (surface)")
    name = props.get("name")
    if not isinstance(name, str) or not name:
        raise MapError(f"{path}: feature {i} (surface) needs a 'name'")
    crr = _crr(props.get("crr"), f"feature {i} (surface '{name}')", path)
    return Surface(name, crr, geom)


def _crr(value, what: str, path: Path) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise MapError(f"{path}: {what} needs a numeric 'crr', got {value!r}")
    if not 0.0 <= value <= 1.0:
        raise MapError(f"{path}: {what} has crr = {value} outside [0, 1]")
    return float(value)


def _home(found, boundary, keep_out, path: Path):
    if not found:
        return None
    if len(found) > 1:
        raise MapError(f"{path}: more than one home feature (features {[f[0] for f in found]})")
    i, geom, _ = found[0]
    if not isinstance(geom, Point):
        raise MapError(f"{path}: feature {i} (home) must be a Point")
    if not boundary.covers(geom):
        raise MapError(f"{path}: feature {i} (home) lies outside the boundary")
    for zone in keep_out:
        if zone.intersects(geom):
            raise MapError(f"{path}: feature {i} (home) lies inside an obstacle or no-go zone")
    return (geom.x, geom.y)


def _default_surface(value, path: Path):
    if value is None:
        return None
    if not isinstance(value, dict) or "name" not in value or "crr" not in value:
        raise MapError(f"{path}: default_surface must be {{\"name\": ..., \"crr\": ...}}")
    return (str(value["name"]), _crr(value["crr"], "default_surface", path))


def _check_covers(raster: ElevationRaster, boundary: Polygon, name: str, path: Path) -> None:
    xmin, ymin, xmax, ymax = raster.bounds_m
    bx0, by0, bx1, by1 = boundary.bounds
    tol = 1e-6
    if bx0 < xmin - tol or by0 < ymin - tol or bx1 > xmax + tol or by1 > ymax + tol:
        raise MapError(
            f"{path}: elevation raster '{name}' covers x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g} m "
            f"but the boundary spans x {bx0:g}..{bx1:g}, y {by0:g}..{by1:g} m"
        )
