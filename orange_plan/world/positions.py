"""The one rule for reported positions (recordings, telemetry batches): on the map or not.

A position far outside the map's boundary box is in another frame or from another origin
(degrees for metres, a wrong origin, a corrupt sample): nothing computed from it means
anything, so it is refused, naming the position. A position on the map but outside its free
space (``World.is_free``: inside an obstacle or no-go zone within the robot's size, or just
past the boundary: GNSS noise) is not refused here: the robot is not where the map says it
can be, and what follows from it is the caller's to say (a mission decision flags it).
"""

from __future__ import annotations

import numpy as np

from orange_plan.errors import InputError

OFF_MAP_TOLERANCE = 0.1
"""Positions may stray outside the map's boundary box by this fraction of its larger side
(at least ``OFF_MAP_MIN_M``): GNSS noise, a robot parked at the edge."""
OFF_MAP_MIN_M = 10.0


def off_map_tolerance_m(world) -> float:
    """How far outside the map's boundary box a position may lie and still count as on the
    map [m]."""
    x0, y0, x1, y1 = world.true_map.boundary.bounds
    return max(OFF_MAP_MIN_M, OFF_MAP_TOLERANCE * max(x1 - x0, y1 - y0))


def distance_off_map_m(world, x_m, y_m) -> np.ndarray:
    """Distance of each position beyond the map's boundary box (0 inside it) [m]."""
    x, y = np.broadcast_arrays(np.asarray(x_m, float), np.asarray(y_m, float))
    x0, y0, x1, y1 = world.true_map.boundary.bounds
    return np.maximum.reduce([x0 - x, x - x1, y0 - y, y - y1, np.zeros(x.shape)])


def check_on_map(world, x_m, y_m, source: str, row: str = "sample") -> None:
    """Refuse positions far outside the map (another frame or origin).

    A position that passes may still lie outside the map's free space (``World.is_free``):
    the session flags that, predict and calibrate take the recorded motion as it is.

    Parameters
    ----------
    world : the World the positions are meant to lie in
    x_m, y_m : positions [m] (1-D arrays)
    source : what the positions come from, first in the message ("samples", a file)
    row : what one position is called in the message ("sample", "row")

    Raises
    ------
    InputError
        Naming how many positions lie beyond the map's boundary box (with its tolerance),
        the first such position, its index and how far off it is.
    """
    x, y = np.atleast_1d(np.asarray(x_m, float)), np.atleast_1d(np.asarray(y_m, float))
    off = distance_off_map_m(world, x, y)
    tol = off_map_tolerance_m(world)
    far = ~(off <= tol)  # a NaN position is not on the map either
    if far.any():
        i = int(np.flatnonzero(far)[0])
        x0, y0, x1, y1 = world.true_map.boundary.bounds
        raise InputError(
            f"{source}: {int(far.sum())} of {len(x)} positions lie more than {tol:g} m outside "
            f"the map's boundary box (x {x0:g}..{x1:g}, y {y0:g}..{y1:g} m), the first at "
            f"{row} {i}: ({x[i]:g}, {y[i]:g}) m, {off[i]:.3g} m off; is it in the map's frame "
            "(x east, y north, metres from its origin)?")
