"""Routes to drive: a plan GeoJSON's tour or a CSV of x_m, y_m[, speed_mps] waypoints."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from orange_plan.errors import InputError
from orange_plan.export.missions_in import read_route_columns
from orange_plan.files import read_json, require_file
from orange_plan.planning.plan import read_tour

PLAN_SUFFIXES = (".geojson", ".json")
"""File endings read as a plan GeoJSON; anything else is read as a route CSV."""


@dataclass(frozen=True)
class Route:
    """A polyline with a commanded speed per vertex.

    Attributes
    ----------
    xy_m : vertices, shape (n, 2) [m]
    speed_mps : commanded speed per vertex, shape (n,), NaN where the file gave none [m/s]
    source : where it came from
    """

    xy_m: np.ndarray
    speed_mps: np.ndarray
    source: str

    @property
    def length_m(self) -> float:
        """Horizontal length [m]."""
        return float(np.sum(np.hypot(*np.diff(self.xy_m, axis=0).T)))

    @property
    def closed(self) -> bool:
        """True when the route ends where it starts (a tour home -> home)."""
        return bool(np.hypot(*(self.xy_m[-1] - self.xy_m[0])) < 1e-6)

    def lap(self) -> Route:
        """A closed route to repeat: itself if closed, else out and back."""
        if self.closed:
            return self
        return Route(np.vstack([self.xy_m, self.xy_m[-2::-1]]),
                     np.r_[self.speed_mps, self.speed_mps[-2::-1]], self.source)

    def with_default_speed(self, speed_mps: float) -> Route:
        """Fill vertices without a speed (NaN or <= 0) with ``speed_mps``."""
        v = np.where(np.isfinite(self.speed_mps) & (self.speed_mps > 0), self.speed_mps, speed_mps)
        return Route(self.xy_m, v, self.source)


def load_route(path: str | Path) -> Route:
    """Read a plan GeoJSON (the ``tour`` LineString and its ``speed_mps``) or a route CSV.

    Raises
    ------
    InputError
        File missing or unreadable, no tour, fewer than two distinct vertices, non-finite or
        negative values, speed array of the wrong length.
    """
    path = Path(path)
    require_file(path, "route")
    if path.suffix.lower() in PLAN_SUFFIXES:
        xy, speed = _from_plan(path)
    else:
        xy, speed = _from_csv(path)
    if xy.ndim != 2 or xy.shape[1] != 2 or not np.all(np.isfinite(xy)):
        raise InputError(f"{path}: route vertices must be finite (x, y) pairs")
    keep = np.r_[True, np.hypot(*np.diff(xy, axis=0).T) > 1e-9]  # drop repeated vertices
    xy, speed = xy[keep], speed[keep]
    if len(xy) < 2:
        raise InputError(f"{path}: a route needs at least two distinct vertices")
    if np.any(speed[np.isfinite(speed)] < 0):
        raise InputError(f"{path}: speed_mps must be >= 0")
    return Route(xy, speed, str(path))


def _from_plan(path: Path):
    """The tour's vertices and speeds (NaN where the file has none) of a plan file."""
    xy, arrays = read_tour(read_json(path, "plan GeoJSON"), str(path))
    speed = arrays["speed_mps"]
    return xy, np.full(len(xy), np.nan) if speed is None else speed


def _from_csv(path: Path):
    cols = read_route_columns(path, ("speed_mps",))
    xy = np.column_stack([cols["x_m"], cols["y_m"]])
    speed = cols["speed_mps"]
    return xy, speed
