"""Meteorological wind (or water current) <-> vector, the reference-model convention.

``from_deg`` is the direction the wind blows *from*, clockwise from north (0 = from the
north, so it blows south); the vector is (x east, y north) [m/s]. Works on scalars and arrays.
"""

from __future__ import annotations

import numpy as np


def wind_vector_mps(speed_mps, from_deg):
    """``w = -speed (sin(from), cos(from))`` (x east, y north) [m/s]."""
    rad = np.radians(from_deg)
    return -speed_mps * np.sin(rad), -speed_mps * np.cos(rad)


def wind_xy_mps(speed_mps: float, from_deg: float) -> tuple[float, float]:
    """``wind_vector_mps`` of one wind as a pair of floats (x east, y north) [m/s]."""
    wx, wy = wind_vector_mps(speed_mps, from_deg)
    return float(wx), float(wy)


def wind_speed_and_from(wind_x_mps, wind_y_mps):
    """Inverse of ``wind_vector_mps``: speed [m/s] and from-direction in [0, 360) [deg]."""
    return (np.hypot(wind_x_mps, wind_y_mps),
            np.degrees(np.arctan2(-np.asarray(wind_x_mps), -np.asarray(wind_y_mps))) % 360.0)
