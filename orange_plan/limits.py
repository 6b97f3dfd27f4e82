"""Size limits: the largest grids, roadmaps and rasters a user's settings may ask for.

Every size a user can set (roadmap vertices, the sensor radius against the map, a raster
file's cells) is checked against one of these constants before anything of that size is
allocated, and refused in one line (``InputError``: exit code 2, HTTP 422) that names the
setting and the limit. The command line, the Python API and the HTTP service read the same
constants.
"""

from __future__ import annotations

import math
from numbers import Integral

from orange_plan.errors import InputError

MIN_ROADMAP_VERTICES = 2
"""Fewest roadmap vertices (``--vertices``, ``n_vertices``): a path needs two."""

MAX_ROADMAP_VERTICES = 20_000
"""Most roadmap vertices (``--vertices``, ``n_vertices``). A roadmap's edges and energy
fields grow with n log n: 20,000 vertices plan in well under a minute and a few hundred MB."""

MAX_COVERAGE_CELLS = 400_000
"""Most cells of the grid that counts sensed area (its cell grows to stay under it)."""

MAX_COVERAGE_LATTICE_POINTS = 150_000
"""Most points of the viewpoint lattice (spacing ``sensor_radius_m * sqrt(3)``, rows
``1.5 * sensor_radius_m`` apart) over the map's bounding box: about its area over
``2.6 * sensor_radius_m ** 2``; the sweep lanes are fewer. Beyond it the coverage grid's cells
(``MAX_COVERAGE_CELLS``) grow larger than the footprint's radius, so sensed area can no longer
be counted. At the limit a plan of the 8 x 6 m lab (``sensor_radius_m`` = 11 mm, 100
vertices) took 26 s of CPU and 470 MB; a smaller radius is refused (one with a lattice of
7.6 million points had run for 15 minutes at 2 GB without an answer)."""

MAX_RASTER_CELLS = 2_000_000
"""Most cells of the terrain rasters (occupancy, rolling coefficient, surface) built from a
map (their cell grows to stay under it): about 50 MB."""

MAX_ELEVATION_CELLS = 25_000_000
"""Most cells of an elevation raster file (rows x columns; 200 MB as 64-bit floats)."""


def check_roadmap_vertices(n_vertices) -> int:
    """``n_vertices`` as an int in [MIN_ROADMAP_VERTICES, MAX_ROADMAP_VERTICES].

    Raises
    ------
    InputError
        Not an integer, or outside the limits (one line naming both limits).
    """
    if isinstance(n_vertices, bool) or not isinstance(n_vertices, Integral):
        raise InputError(f"roadmap vertices (--vertices, n_vertices) = {n_vertices!r} must be "
                         "an integer")
    n = int(n_vertices)
    if not MIN_ROADMAP_VERTICES <= n <= MAX_ROADMAP_VERTICES:
        raise InputError(f"roadmap vertices (--vertices, n_vertices) = {n}: must be between "
                         f"{MIN_ROADMAP_VERTICES} and {MAX_ROADMAP_VERTICES:,} (the limit)")
    return n


def smallest_radius_m(area_m2: float, points_per_r2_m2: float, limit: int) -> float:
    """Smallest radius r for which ``area / (points_per_r2 * r^2)`` stays within ``limit``
    [m] (what a refusal tells the user to ask for instead)."""
    return math.sqrt(area_m2 / (points_per_r2_m2 * limit))



MAX_MISSION_WAYPOINTS = 10_000
"""Most waypoints of a mission ``check`` reads (a survey of a few square kilometres has a
few thousand)."""

MAX_MISSION_SAMPLES = 3_000_000
"""Most motion samples (0.1 s each, or sub-steps) of the mission a check drives at once: at
about 300 bytes a sample, under 1 GB (83 hours of flight)."""

MAX_MISSION_HOME_SAMPLES = 30_000_000
"""Most samples of the ways home from every leg end a check drives (in batches, so memory
stays that of one batch; time grows with them: about 10 s of CPU per 10 million)."""
