"""World: a validated map with the scenario's home and ground, with vectorised terrain queries.

The wind (or water current) is not the world's: the mission's conditions hold it
(``physics.conditions.Conditions``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import shapely

from orange_plan.errors import InputError, ScenarioError
from orange_plan.world.geomap import Map, load_map

ARC_SEGMENTS = 16
"""Segments per quarter circle of the arcs that inflation puts round corners."""

ARC_STRETCH = 1.0 / math.cos(math.pi / (4 * ARC_SEGMENTS))
"""Inflation grows by ``keep_away_m * ARC_STRETCH`` (0.12 % more): a buffer's arcs are chords
of the true circle, whose midpoints fall ``1 - cos(pi / 4 q)`` of the radius inside it;
stretched, the chords lie on or outside the circle, so every point of the inflated free space
keeps at least ``keep_away_m`` from the map's geometry."""


def inflate_map(m: Map, keep_away_m: float) -> Map:
    """The free space of a disc robot: the map with obstacles and no-go zones grown and the
    boundary shrunk by ``keep_away_m`` [m] (surfaces, elevation and home unchanged).

    Planning with the inflated map as a point robot keeps the disc's edge off every wall:
    every path, return, reach answer and collision check inherits it. ``keep_away_m = 0``
    returns ``m`` itself.
    """
    if keep_away_m <= 0:
        return m
    grow = keep_away_m * ARC_STRETCH
    return replace(
        m,
        boundary=m.boundary.buffer(-grow, quad_segs=ARC_SEGMENTS),
        obstacles=tuple(o.buffer(grow, quad_segs=ARC_SEGMENTS) for o in m.obstacles),
        no_go=tuple(z.buffer(grow, quad_segs=ARC_SEGMENTS) for z in m.no_go),
    )


@dataclass(frozen=True)
class World:
    """Terrain queries over a map (vectorised: any array shape in, same shape out).

    Attributes
    ----------
    map : the map the robot plans in: ``true_map`` inflated by ``keep_away_m``
        (``inflate_map``); every free-space and collision query reads it
    default_crr : rolling coefficient where no surface polygon applies [-]
    default_surface_name : its name (the map's default_surface, else "default")
    home_xy_m : start and return point [m]
    true_map : the map as given (plus map updates): what the sensor sees (coverage counts
        it up to the walls) and what plots draw; None: ``map``
    keep_away_m : the scenario's ``robot.radius_m + mission.clearance_m`` [m]
    """

    map: Map
    default_crr: float
    default_surface_name: str
    home_xy_m: tuple[float, float]
    true_map: Map | None = None
    keep_away_m: float = 0.0

    def __post_init__(self):
        if self.true_map is None:
            object.__setattr__(self, "true_map", self.map)

    @classmethod
    def from_scenario(cls, scenario, map_: Map | None = None) -> World:
        """Load the scenario's map and combine it with its environment and home override."""
        m = map_ if map_ is not None else load_map(scenario.map_path)
        if m.default_surface is not None:
            default_name, default_crr = m.default_surface
        else:
            default_name, default_crr = "default", scenario.robot.crr
        home = scenario.mission.home_xy_m or m.home_xy_m
        if home is None:
            raise ScenarioError(
                f"{scenario.path}: no home: set mission.home_xy_m or add a 'home' Point to the map"
            )
        keep_away = scenario.keep_away_m
        world = cls(m, default_crr, default_name, tuple(home), keep_away_m=keep_away)
        world = world.with_map(m)
        if world.map.boundary.is_empty or world.map.free_space.is_empty:
            raise ScenarioError(
                f"{scenario.path}: robot.radius_m + mission.clearance_m = {keep_away:g} m leaves "
                f"no room to move: every point of the map is closer than that to its boundary, "
                "an obstacle or a no-go zone"
            )
        problem = world.clearance_problem(home)
        if problem:
            raise ScenarioError(f"{scenario.path}: home {problem}")
        return world

    def with_map(self, true_map: Map) -> World:
        """This world on another map (a map update), inflated by the same ``keep_away_m``."""
        return replace(self, map=inflate_map(true_map, self.keep_away_m), true_map=true_map)

    # --- point queries -----------------------------------------------------------------
    def surface_code_at(self, x_m, y_m) -> np.ndarray:
        """Index into ``map.surface_names`` of the last surface containing each point, -1 if none."""
        x, y = np.broadcast_arrays(np.asarray(x_m, float), np.asarray(y_m, float))
        code = np.full(x.shape, -1, dtype=int)
        names = self.map.surface_names
        for surface in self.map.surfaces:  # later features win where they overlap
            code[shapely.contains_xy(surface.polygon, x, y)] = names.index(surface.name)
        return code

    def crr_at(self, x_m, y_m) -> np.ndarray:
        """Rolling coefficient at each point: last surface containing it, else the default [-]."""
        x, y = np.broadcast_arrays(np.asarray(x_m, float), np.asarray(y_m, float))
        crr = np.full(x.shape, self.default_crr, dtype=float)
        for surface in self.map.surfaces:
            crr[shapely.contains_xy(surface.polygon, x, y)] = surface.crr
        return crr

    def elevation_at(self, x_m, y_m) -> np.ndarray:
        """Ground elevation [m]; flat z = 0 without a raster."""
        x, y = np.broadcast_arrays(np.asarray(x_m, float), np.asarray(y_m, float))
        if self.map.elevation is None:
            return np.zeros(x.shape)
        return self.map.elevation.elevation_at(x, y)

    def is_free(self, x_m, y_m) -> np.ndarray:
        """True where a point is inside the boundary and outside every keep-out zone (of the
        inflated ``map``: at least ``keep_away_m`` from the true ones)."""
        x, y = np.broadcast_arrays(np.asarray(x_m, float), np.asarray(y_m, float))
        free = shapely.intersects_xy(self.map.boundary, x, y)
        keep_out = self.map.keep_out
        if not keep_out.is_empty:
            free &= ~shapely.intersects_xy(keep_out, x, y)
        return free

    def segments_free(self, start_xy, end_xy) -> np.ndarray:
        """True where the straight segment stays in free space (exact, vectorised) (n,)."""
        a, b = np.atleast_2d(start_xy).astype(float), np.atleast_2d(end_xy).astype(float)
        lines = shapely.linestrings(np.stack([a, b], axis=1))
        inside = shapely.covers(self.map.boundary, lines)
        keep_out = self.map.keep_out
        if not keep_out.is_empty:
            inside &= ~shapely.intersects(keep_out, lines)
        return inside

    def check_points(self, xy, what: str = "point") -> None:
        """Raise InputError naming the first point not in free space."""
        xy = np.atleast_2d(np.asarray(xy, float))
        ok = self.is_free(xy[:, 0], xy[:, 1])
        if not np.all(ok):
            i = int(np.flatnonzero(~ok)[0])
            count = f" ({np.count_nonzero(~ok)} of {len(xy)} are)" if len(xy) > 1 else ""
            raise InputError(f"{what} {i} {self.clearance_problem(xy[i])}{count}")

    def clearance_problem(self, xy) -> str | None:
        """Why a point is not in free space, as a phrase to follow its name ("at (x, y) m is
        ..."), or None if it is free."""
        x, y = float(xy[0]), float(xy[1])
        reason = self.why_not_free(x, y)
        return None if reason is None else f"at ({x:g}, {y:g}) m is {reason}"

    def why_not_free(self, x_m: float, y_m: float) -> str | None:
        """None for a point in free space, else why not: outside the boundary, inside an
        obstacle or no-go zone, or nearer an edge than the robot keeps (the distance to the
        nearest obstacle, no-go zone or boundary edge named) [m]."""
        if bool(self.is_free(x_m, y_m)):
            return None
        m = self.true_map
        if not bool(shapely.intersects_xy(m.boundary, x_m, y_m)):
            return "outside the boundary"
        keep_out = m.keep_out
        if not keep_out.is_empty and bool(shapely.intersects_xy(keep_out, x_m, y_m)):
            return "inside an obstacle or no-go zone"
        point = shapely.Point(x_m, y_m)
        distance = m.boundary.boundary.distance(point)  # its rings: exterior and holes
        if not keep_out.is_empty:
            distance = min(distance, keep_out.distance(point))
        return (f"{distance:.3g} m from the nearest obstacle, no-go zone or boundary edge, "
                f"closer than the robot keeps (robot.radius_m + mission.clearance_m = "
                f"{self.keep_away_m:g} m)")

    def check_route(self, xy, source: str = "route") -> None:
        """Raise InputError unless a polyline lies in free space: every vertex and every
        straight segment between them (a route made on another map, or in another frame,
        is refused before anything drives or flies it).

        Parameters
        ----------
        xy : route vertices (n, 2) [m]
        source : the route's file, for the message
        """
        xy = np.atleast_2d(np.asarray(xy, float))
        try:
            self.check_points(xy, "route vertex")
        except InputError as exc:
            raise InputError(f"{source}: {exc}; was the route made on this scenario's "
                             "map?") from None
        free = self.segments_free(xy[:-1], xy[1:])
        if not free.all():
            i = int(np.argmin(free))
            near = (f" or passes closer to its edges than the robot keeps ({self.keep_away_m:g} "
                    "m: robot.radius_m + mission.clearance_m)" if self.keep_away_m > 0 else "")
            raise InputError(f"{source}: route segment {i} leaves the free space of the "
                             f"map{near}")
