"""World: a validated map plus the scenario's environment, with vectorised terrain queries."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from orange_plan.errors import InputError, ScenarioError
from orange_plan.physics.conditions import Conditions
from orange_plan.world.geomap import Map, load_map


@dataclass(frozen=True)
class World:
    """Terrain queries over a map (vectorised: any array shape in, same shape out).

    Attributes
    ----------
    map : the validated Map
    default_crr : rolling coefficient where no surface polygon applies [-]
    default_surface_name : its name (the map's default_surface, else "default")
    wind_xy_mps : the scenario's ``Conditions`` wind (or water current) (x east, y north)
        [m/s], kept only as the fallback wind of recordings without wind columns
        (``telemetry.state``); planning and simulation read ``Context.conditions``
    home_xy_m : start and return point [m]
    """

    map: Map
    default_crr: float
    default_surface_name: str
    wind_xy_mps: tuple[float, float]
    home_xy_m: tuple[float, float]

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
        wind = Conditions.of(scenario).wind_xy_mps
        world = cls(m, default_crr, default_name, wind, tuple(home))
        if not bool(world.is_free(*home)):
            raise ScenarioError(
                f"{scenario.path}: home {tuple(home)} lies outside the boundary or inside an "
                "obstacle / no-go zone"
            )
        return world

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
        """True where a point is inside the boundary and outside every keep-out zone."""
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
            raise InputError(
                f"{what} {i} at ({xy[i, 0]:g}, {xy[i, 1]:g}) m is outside the boundary or inside "
                f"an obstacle / no-go zone{count}"
            )

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
            raise InputError(f"{source}: route segment {i} leaves the free space of the map")
