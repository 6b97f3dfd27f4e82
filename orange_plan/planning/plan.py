"""The plan a tour planner returns, and its SPEC §4 GeoJSON form.

A ``Plan`` is data only: per-vertex arrays along the tour (start -> ... -> home), the visited
waypoints, the sensed area and the summary figures. ``planning.tour`` makes plans; the
``plan`` command, the simulator, the figures and the replanning session read them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import mapping

from orange_plan.atomic import atomic_path

VERTEX_ARRAYS = ("t_s", "speed_mps", "energy_used_J", "energy_to_home_J", "margin_J")
"""SPEC §4 per-vertex properties of the tour LineString (same length as its coordinates)."""

SUMMARY_KEYS = ("energy_available_J", "energy_planned_J", "reserve_J", "coverage_m2",
                "coverage_fraction", "coverage_bound_m2", "duration_s", "return_probability",
                "planner_seconds")
"""SPEC §4 keys of the plan's top-level ``summary``."""


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
    """An exploration tour from a start state back home (SPEC §4).

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
    reserve_J : reserve kept at each vertex (SPEC §2 / §7) [J]
    margin_J : energy_available - energy_used - energy_to_home - reserve, >= 0 [J]
    waypoints_xy_m : the chosen coverage candidates' anchor points in visiting order [m]
    covered : the sensed area (start state's covered area included), shapely geometry [m^2]
    summary : SPEC §4 summary figures (``SUMMARY_KEYS``) plus extras
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
        """The SPEC §4 FeatureCollection (tour, waypoints, covered, summary; with a closed-loop
        continuation, a LineString feature of kind ``continuation``)."""
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
        """Write the SPEC §4 GeoJSON atomically."""
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
