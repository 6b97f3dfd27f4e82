"""Point-to-point paths over the energy roadmap, re-evaluated exactly.

A roadmap answer is a polyline a robot can drive: its edges passed the exact collision test,
and its energy is re-evaluated with ``physics.pathcost.path_energy`` (exact terrain, reference-model
sub-steps, turning at interior vertices), so the figure reported is that path's energy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from orange_plan.errors import PlanningError
from orange_plan.physics.pathcost import (
    heading_changes_rad,
    path_energy,
    segments_energy,
    segments_energy_jacobian,
    subdivide,
)
from orange_plan.physics.profile import profile_gradient
from orange_plan.planning.roadmap import (
    EdgeCostContext,
    Roadmap,
    add_vertices,
    energy_field,
    ompl_raster_setup,
    walk_predecessors,
)


@dataclass(frozen=True)
class PlannedPath:
    """A drivable polyline with its exact energy at the cruise speed.

    Attributes
    ----------
    xy_m : vertices, shape (n, 2) [m]
    energy_J : battery energy of the whole path (path_energy: reference-model sub-steps, and the
        driven speed profile when the cost carries an acceleration limit) [J]
    length_m : horizontal length [m]
    duration_s : mission time, stops included [s]
    speed_mps : cruise speed [m/s]
    method : how it was found ("roadmap energy", "roadmap shortest", "BIT*")
    """

    xy_m: np.ndarray
    energy_J: float
    length_m: float
    duration_s: float
    speed_mps: float
    method: str


MIN_STEP_M = 1e-9
"""Vertices closer than this to the one before are duplicates (no heading between) [m]."""


def distinct_vertices(xy) -> np.ndarray:
    """Mask of a polyline's vertices to keep: the first, and each one more than
    ``MIN_STEP_M`` from the vertex before it."""
    p = np.asarray(xy, float).reshape(-1, 2)
    return np.r_[True, np.hypot(*np.diff(p, axis=0).T) > MIN_STEP_M][:len(p)]


def dedupe(xy) -> np.ndarray:
    """Drop consecutive duplicate vertices (no padding)."""
    p = np.asarray(xy, float).reshape(-1, 2)
    return p[distinct_vertices(p)]


def clean_polyline(xy) -> np.ndarray:
    """Drop consecutive duplicate vertices (a zero-length step has no heading); at least
    two vertices (a lone point is repeated)."""
    p = dedupe(xy)
    return p if len(p) >= 2 else np.vstack([p, p])


def evaluate_path(cost: EdgeCostContext, xy, method: str) -> PlannedPath:
    """Exact energy of a polyline at the cost's cruise speed (``path_energy``; the driven
    speed profile when the cost carries the robot's acceleration limit)."""
    p = clean_polyline(xy)
    e = path_energy(cost.model, cost.world, p, cost.speed_mps, cost.conditions,
                    cost.accel_max_mps2)
    length = float(np.sum(np.hypot(*np.diff(p, axis=0).T)))
    return PlannedPath(p, e.total_J, length, e.duration_s, float(cost.speed_mps), method)


def path_gradient(cost: EdgeCostContext, xy) -> np.ndarray:
    """d(path energy)/d theta of a polyline (exact terrain, turning included), shape (k,):
    of the driven profile when the cost carries an acceleration limit, else of the reference model.

    With the model's covariance, ``model.energy_variance_J2(gradient)`` is the variance of the
    path's energy (reserve sizing).
    """
    p = clean_polyline(xy)
    model = cost.model
    steps = subdivide(cost.world, p[:-1], p[1:])
    if cost.accel_max_mps2 is not None and np.any(steps.horiz_m > 0):
        # the energy path_energy reports for this cost is the driven profile's
        return profile_gradient(model, steps, steps.per_step(cost.speed_mps), cost.accel_max_mps2,
                                cost.conditions)
    jac = segments_energy_jacobian(model, cost.world, steps, cost.speed_mps,
                                   cost.conditions).sum(axis=0)
    if len(p) > 2:
        # Zero length: only the rate (turning) columns are non-zero.
        from orange_plan.physics.state import MotionState

        turns = heading_changes_rad(p)
        still = MotionState(speed_mps=np.ones_like(turns))
        jac = jac + model.segment_energy_jacobian(still, np.zeros_like(turns),
                                                  cost.conditions.duty_cycle,
                                                  turns).sum(axis=0)
    return jac


def roadmap_path(cost: EdgeCostContext, roadmap: Roadmap, start_xy, goal_xy,
                 weight: str = "energy") -> PlannedPath:
    """Best roadmap path from ``start_xy`` to ``goal_xy`` by energy or by length.

    Parameters
    ----------
    weight : "energy" (minimum battery energy) or "length" (shortest path, for comparison)

    Raises
    ------
    PlanningError
        If the two points are not connected through the roadmap.
    """
    extended = add_vertices(cost, roadmap, np.array([start_xy, goal_xy], float))
    s, g = roadmap.n_vertices, roadmap.n_vertices + 1
    if weight == "energy":
        field = energy_field(extended, s, towards=False)
        if not np.isfinite(field.energy_J[g]):
            raise PlanningError(f"no roadmap path from {tuple(start_xy)} to {tuple(goal_xy)}")
        seq = field.path(g)
    else:
        seq = _shortest(extended, s, g)
    return evaluate_path(cost, extended.xy_m[seq], f"roadmap {weight}")


def _shortest(roadmap: Roadmap, s: int, g: int) -> list[int]:
    n = roadmap.n_vertices
    length = np.hypot(*(roadmap.xy_m[roadmap.dst] - roadmap.xy_m[roadmap.src]).T)
    graph = csr_matrix((np.maximum(length, 1e-9), (roadmap.src, roadmap.dst)), shape=(n, n))
    dist, pred = dijkstra(graph, indices=s, return_predecessors=True)
    if not np.isfinite(dist[g]):
        raise PlanningError("no roadmap path between the two points")
    return walk_predecessors(pred, s, g)[::-1]


def segment_energy_J(cost: EdgeCostContext, x0: float, y0: float, x1: float, y1: float) -> float:
    """Energy of one straight segment with the cost's terrain and sub-step (scalar) [J]."""
    steps = subdivide(cost.world, [[x0, y0]], [[x1, y1]], cost.step_m, terrain=cost.terrain)
    e = segments_energy(cost.model, cost.world, None, None, cost.speed_mps, cost.conditions,
                        steps=steps)
    return float(e.total_J[0])


def bitstar_path(cost: EdgeCostContext, exact: EdgeCostContext, start_xy, goal_xy,
                 seconds: float = 1.0, seed: int = 0) -> PlannedPath | None:
    """Minimum-energy path by OMPL BIT* with an asymmetric energy objective.

    Validity on the occupancy raster, motion cost from ``physics.pathcost`` (``cost``); the
    result is checked exactly and re-evaluated with ``exact``. None if BIT* finds no exact
    solution in ``seconds`` or its path fails the exact collision test.
    """
    from ompl import base as ob
    from ompl import geometric as og

    terrain, world = cost.terrain, cost.world
    ss, si, space, valid = ompl_raster_setup(world, terrain, seed)
    xmin, ymin, xmax, ymax = world.map.boundary.bounds
    extent = float(np.hypot(xmax - xmin, ymax - ymin))
    si.setStateValidityCheckingResolution(min(0.5, 0.5 * terrain.cell_m / extent))

    class EnergyObjective(ob.OptimizationObjective):
        def stateCost(self, s):
            return ob.Cost(0.0)

        def motionCost(self, s1, s2):
            return ob.Cost(segment_energy_J(cost, s1[0], s1[1], s2[0], s2[1]))

        def isSymmetric(self):  # climbing != descending: the cost of a path depends on its direction
            return False

    a, b = si.allocState(), si.allocState()
    a[0], a[1] = start_xy
    b[0], b[1] = goal_xy
    ss.setStartAndGoalStates(a, b)
    ss.setOptimizationObjective(EnergyObjective(si))
    ss.setPlanner(og.BITstar(si))
    ss.solve(float(seconds))
    xy = None
    if ss.haveExactSolutionPath():
        path = ss.getSolutionPath()
        xy = np.array([[path.getState(i)[0], path.getState(i)[1]]
                       for i in range(path.getStateCount())])
    del ss, si, space, valid, a, b
    if xy is None or not world.segments_free(xy[:-1], xy[1:]).all():
        return None
    return evaluate_path(exact, xy, "BIT*")


def refined_path(cost: EdgeCostContext, exact: EdgeCostContext, roadmap: Roadmap, start_xy,
                 goal_xy, seconds: float = 1.0, seed: int = 0) -> PlannedPath:
    """The roadmap answer, replaced by BIT*'s when BIT* finds a cheaper drivable path."""
    best = roadmap_path(exact, roadmap, start_xy, goal_xy)
    bit = bitstar_path(cost, exact, start_xy, goal_xy, seconds, seed)
    return bit if bit is not None and bit.energy_J < best.energy_J else best


def cut_path(xy, s_m: float) -> np.ndarray:
    """The polyline from its start to arclength ``s_m`` (the cut point included) [m]."""
    xy = np.asarray(xy, float)
    s0 = np.r_[0.0, np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]
    if s_m >= s0[-1]:
        return xy.copy()
    j = int(np.searchsorted(s0, s_m, side="right")) - 1
    u = (s_m - s0[j]) / max(s0[j + 1] - s0[j], 1e-18)
    end = xy[j] + u * (xy[j + 1] - xy[j])
    return clean_polyline(np.vstack([xy[: j + 1], end]))
