"""The plan a tour planner returns, and its GeoJSON form (docs/formats.md, "Plan").

A ``Plan`` is data only: per-vertex arrays along the tour (start -> ... -> home), the visited
waypoints, the sensed area and the summary figures. ``planning.tour`` makes plans; the
``plan`` command, the simulator, the figures and the replanning session read them.
``Plan.to_geojson`` writes the file's form and ``plan_from_geojson`` (``read_tour`` for the
tour alone) reads it back: the one reader of plan files.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import mapping, shape

from orange_plan.atomic import atomic_path
from orange_plan.errors import InputError

VERTEX_ARRAYS = ("t_s", "speed_mps", "energy_used_J", "energy_to_home_J", "margin_J")
"""Per-vertex properties of the tour LineString (same length as its coordinates)."""

SUMMARY_KEYS = ("energy_available_J", "energy_planned_J", "reserve_J", "coverage_m2",
                "coverage_fraction", "coverage_bound_m2", "duration_s", "return_probability",
                "planner_seconds")
"""Keys of the plan's top-level ``summary``."""


@dataclass(frozen=True)
class StartState:
    """Where a (re)plan starts: mid-mission position, energy and coverage so far.

    Attributes
    ----------
    xy_m : robot position [m]; None: home
    energy_used_J : battery energy already used [J]
    time_s : mission time already elapsed [s]
    covered : area already sensed (shapely geometry) or None
    """

    xy_m: tuple[float, float] | None = None
    energy_used_J: float = 0.0
    time_s: float = 0.0
    covered: object = None


@dataclass(frozen=True)
class Plan:
    """An exploration tour from a start state back home.

    Attributes
    ----------
    xy_m : tour vertices, shape (n, 2), first = start, last = home [m]
    t_s : mission time at each vertex (stops included, from the start state's time) [s]
    speed_mps : commanded speed on the segment leaving each vertex (last: that of the
        arriving segment) [m/s]
    energy_used_J : battery energy used on arrival at each vertex, including the start
        state's ``energy_used_J`` [J]
    energy_to_home_J : planned energy of the return home from each vertex at the cruise
        speed [J]
    reserve_J : reserve kept at each vertex (``mission.reserve``) [J]
    margin_J : energy_available - energy_used - energy_to_home - reserve, >= 0 [J]
    waypoints_xy_m : the chosen coverage candidates' anchor points in visiting order [m]
    covered : the sensed area (start state's covered area included), shapely geometry [m^2]
    summary : the summary figures (``SUMMARY_KEYS``) plus extras
    continuation_xy_m : where a robot that measures its energy in flight goes on after the
        guaranteed extent (from the tour's turn point; it ends at home), turning home on the
        live check; None: the tour is the whole route [m]
    """

    xy_m: np.ndarray
    t_s: np.ndarray
    speed_mps: np.ndarray
    energy_used_J: np.ndarray
    energy_to_home_J: np.ndarray
    reserve_J: np.ndarray
    margin_J: np.ndarray
    waypoints_xy_m: np.ndarray
    covered: object
    summary: dict = field(default_factory=dict)
    continuation_xy_m: np.ndarray | None = None

    @property
    def n_vertices(self) -> int:
        return len(self.xy_m)

    def closed_loop_route(self) -> tuple[np.ndarray, np.ndarray, int]:
        """The route a closed loop flies: the tour up to its turn point, then the
        continuation (the tour itself without one) [m]; the commanded speed at each vertex
        (the tour's, then the cruise speed the sweep was scored at) [m/s]; and the index of
        the turn point (the last vertex of the guaranteed extent)."""
        xy = np.asarray(self.xy_m, float)
        speed = np.asarray(self.speed_mps, float)
        rest = self.continuation_xy_m
        if rest is None or len(rest) < 2:
            return xy, speed, len(xy) - 1
        turn = np.flatnonzero(np.hypot(*(xy - np.asarray(rest[0], float)).T) < 1e-6)
        if turn.size == 0:
            return xy, speed, len(xy) - 1
        k = int(turn[0])
        cruise = float(self.summary.get("closed_loop_speed_mps", np.median(speed[: k + 1])))
        route = np.vstack([xy[: k + 1], np.asarray(rest, float)[1:]])
        return route, np.r_[speed[: k + 1], np.full(len(rest) - 1, cruise)], k

    def expected_continuation_xy_m(self) -> np.ndarray | None:
        """The part of the continuation a closed loop is expected to fly before turning home
        (to ``summary["closed_loop_turn_m"]`` along the route), None without one [m]."""
        from orange_plan.planning.paths import cut_path

        rest = self.continuation_xy_m
        if rest is None or len(rest) < 2:
            return None
        beyond = float(self.summary.get("closed_loop_turn_m", 0.0)
                       - self.summary.get("guaranteed_length_m", 0.0))
        return cut_path(rest, beyond) if beyond > 0 else None

    def to_geojson(self) -> dict:
        """The plan file's FeatureCollection (tour, waypoints, covered, summary; with a
        closed-loop continuation, a LineString feature of kind ``continuation``)."""
        tour = {
            "type": "Feature",
            "properties": {"kind": "tour",
                           **{k: _floats(getattr(self, k)) for k in VERTEX_ARRAYS},
                           "reserve_J": _floats(self.reserve_J)},
            "geometry": {"type": "LineString", "coordinates": _floats(self.xy_m)},
        }
        waypoints = [{"type": "Feature", "properties": {"kind": "waypoint", "order": i},
                      "geometry": {"type": "Point", "coordinates": _floats(p)}}
                     for i, p in enumerate(np.asarray(self.waypoints_xy_m).reshape(-1, 2))]
        covered = shapely.geometry.MultiPolygon() if self.covered is None else self.covered
        if covered.geom_type not in ("Polygon", "MultiPolygon"):
            covered = shapely.geometry.MultiPolygon(
                [g for g in getattr(covered, "geoms", []) if g.geom_type == "Polygon"])
        cover = {"type": "Feature", "properties": {"kind": "covered"},
                 "geometry": mapping(covered)}
        extra = []
        if self.continuation_xy_m is not None and len(self.continuation_xy_m) >= 2:
            extra.append({"type": "Feature", "properties": {"kind": "continuation"},
                          "geometry": {"type": "LineString",
                                       "coordinates": _floats(self.continuation_xy_m)}})
        return {"type": "FeatureCollection",
                "summary": {k: _plain(v) for k, v in self.summary.items()},
                "features": [tour, *waypoints, cover, *extra]}

    def write(self, path: str | Path) -> Path:
        """Write the plan's GeoJSON atomically."""
        text = json.dumps(self.to_geojson(), allow_nan=False)
        with atomic_path(path, suffix=".geojson") as tmp:
            tmp.write_text(text, encoding="utf-8")
        return Path(path)


def _floats(a) -> list:
    return np.round(np.asarray(a, float), 6).tolist()


def _plain(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    return v


TOUR_ARRAYS = (*VERTEX_ARRAYS, "reserve_J")
"""Per-vertex arrays a plan file's tour may carry, in its properties."""


def _features(data, kind: str) -> list[dict]:
    features = data.get("features") if isinstance(data, dict) else None
    return [f for f in features or [] if isinstance(f, dict)
            and (f.get("properties") or {}).get("kind") == kind]


def read_tour(data, source: str = "plan") -> tuple[np.ndarray, dict[str, np.ndarray | None]]:
    """The tour of a plan file's GeoJSON ``data``: its vertices (n, 2) [m] and each per-vertex
    array of ``TOUR_ARRAYS`` (None when the file has none).

    Raises
    ------
    InputError
        No feature of kind ``tour``, a tour that is not a LineString, coordinates or arrays
        that are not numbers, an array whose length is not the tour's; the message starts
        with ``source`` (the file's name).
    """
    tours = _features(data, "tour")
    if not tours:
        raise InputError(f"{source}: no feature with kind = 'tour' (a plan's tour LineString)")
    geom = tours[0].get("geometry") or {}
    if geom.get("type") != "LineString":
        raise InputError(f"{source}: the tour must be a LineString, got {geom.get('type')!r}")
    try:
        xy = np.asarray([c[:2] for c in geom.get("coordinates", [])], dtype=float).reshape(-1, 2)
    except (TypeError, ValueError, IndexError):
        raise InputError(f"{source}: tour coordinates must be numbers") from None
    props = tours[0].get("properties") or {}
    arrays: dict[str, np.ndarray | None] = {}
    for key in TOUR_ARRAYS:
        if props.get(key) is None:
            arrays[key] = None
            continue
        try:
            values = np.asarray(props[key], dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"{source}: tour {key} must be numbers") from None
        if values.shape != (len(xy),):
            raise InputError(f"{source}: tour {key} has {values.size} values for {len(xy)} "
                             "vertices")
        arrays[key] = values
    return xy, arrays


def plan_from_geojson(data, source: str = "plan") -> Plan:
    """A Plan from its GeoJSON (``Plan.to_geojson``); per-vertex arrays the file lacks read
    as zeros.

    Raises
    ------
    InputError
        As ``read_tour``.
    """
    xy, arrays = read_tour(data, source)
    filled = {k: np.zeros(len(xy)) if v is None else v for k, v in arrays.items()}
    waypoints = [f["geometry"]["coordinates"] for f in _features(data, "waypoint")]
    covered = next((shape(f["geometry"]) for f in _features(data, "covered")), None)
    rest = next((f["geometry"]["coordinates"] for f in _features(data, "continuation")), None)
    continuation = None if rest is None else np.asarray(rest, float).reshape(-1, 2)
    return Plan(xy, waypoints_xy_m=np.asarray(waypoints, float).reshape(-1, 2), covered=covered,
                summary=dict(data.get("summary", {})), continuation_xy_m=continuation,
                **filled)
