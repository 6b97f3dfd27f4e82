"""Energy roadmap: OMPL PRM* geometry, directed energy weights in numpy, Dijkstra fields.

The geometry comes from OMPL's PRM* grown without ``solve()`` (a Python objective in PRM's
``solve()`` deadlocks), copied to numpy at once; no OMPL object outlives
``roadmap_geometry``. Every undirected edge is re-checked with the exact shapely test, then
weighted in both directions by the scenario's EnergyModel (``physics.pathcost``): the cost is
asymmetric (climbing costs, descending gives nothing back without regen). Dijkstra on the
graph and on its transpose gives the energy-from-home and energy-to-home fields.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import shapely
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from orange_plan.errors import PlanningError
from orange_plan.limits import check_roadmap_vertices
from orange_plan.physics.conditions import Conditions
from orange_plan.physics.pathcost import (
    Steps,
    segments_energy,
    segments_energy_jacobian,
    subdivide,
)

MIN_EDGE_J = 1e-9
"""Smallest edge weight [J]: scipy's sparse graphs drop explicit zeros, which would cut edges."""

WEIGH_CHUNK = 8192
"""Edges weighed at once: the sub-step arrays of all 150k edges of a 5000-vertex roadmap
took ~350 MB at once; in chunks of this size they take a few tens of MB, at the same speed."""


@dataclass(frozen=True)
class Roadmap:
    """A directed roadmap weighted by battery energy at one cruise speed.

    Attributes
    ----------
    xy_m : vertex positions, shape (n, 2) [m]
    src, dst : directed edges (every undirected edge appears both ways), shape (m,)
    energy_J : battery energy of each directed edge at ``speed_mps`` [J]
    jacobian : d energy / d theta of each edge, shape (m, k); (m, 0) if not computed
    speed_mps : cruise speed the weights are computed at [m/s]
    home_index : index of the home vertex
    """

    xy_m: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    energy_J: np.ndarray
    jacobian: np.ndarray
    speed_mps: float
    home_index: int

    @property
    def n_vertices(self) -> int:
        return len(self.xy_m)

    def graph(self) -> csr_matrix:
        """Sparse matrix G with G[i, j] = energy of edge i -> j [J]."""
        n = self.n_vertices
        return csr_matrix((np.maximum(self.energy_J, MIN_EDGE_J), (self.src, self.dst)), shape=(n, n))

    def edge_index(self) -> csr_matrix:
        """Sparse matrix with (edge index + 1) at [i, j]: maps a vertex pair to its edge."""
        n = self.n_vertices
        return csr_matrix((np.arange(len(self.src)) + 1, (self.src, self.dst)), shape=(n, n))


@dataclass(frozen=True)
class EdgeCostContext:
    """What edge weights depend on besides geometry (model, world, speed, conditions)."""

    model: object
    world: object
    terrain: object  # TerrainRasters (fast crr look-ups) or the World itself (exact)
    speed_mps: float
    conditions: Conditions  # duty cycle, sensor rate, wind: the Context's
    step_m: float | None = None  # integration sub-step; None: the reference-model sub-step
    with_gradient: bool = True  # also compute d energy / d theta (confidence reserves)
    # the robot's acceleration limit: exact path energies follow the driven speed profile
    # (ramps, duty-cycle stops); edge weights stay reference-model figures (they only rank paths)
    accel_max_mps2: float | None = None

    def costs(self, start_xy, end_xy):
        """Energies and jacobians of segments a -> b and b -> a.

        Returns
        -------
        (energy_fwd_J, energy_rev_J, jac_fwd, jac_rev): energies (n,) [J]; jacobians (n, k),
        or (n, 0) when ``with_gradient`` is False.

        Notes
        -----
        The reverse segment has the same sub-steps with rise and direction negated, so the
        terrain (the expensive part) is sampled once for both directions.
        """
        fwd = subdivide(self.world, start_xy, end_xy, self.step_m, terrain=self.terrain)
        out_e, out_j = [], []
        for steps in (fwd, reverse_steps(fwd)):
            args = (self.model, self.world)
            rest = (self.speed_mps, self.conditions)
            out_e.append(segments_energy(*args, None, None, *rest, steps=steps).total_J)
            if self.with_gradient:
                out_j.append(segments_energy_jacobian(*args, steps, *rest))
            else:
                out_j.append(np.zeros((steps.n_segments, 0)))
        return out_e[0], out_e[1], out_j[0], out_j[1]


def reverse_steps(steps: Steps) -> Steps:
    """The same sub-steps travelled the other way (rise and direction negated)."""
    return replace(steps, dz_m=-steps.dz_m, dir_x=-steps.dir_x, dir_y=-steps.dir_y)


def ompl_raster_setup(world, terrain, seed: int = 0):
    """An OMPL SimpleSetup over the map's bounding box, valid where the occupancy raster is free.

    Returns ``(ss, si, space, valid)``; the caller keeps all four alive while OMPL runs (the
    Python validity checker is only referenced from C++) and drops them before returning.
    """
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    # OMPL accepts a seed only before its first random number in the process; later calls
    # log an error and are ignored, hence the silenced log around it.
    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    ou.RNG.setSeed(int(seed) + 1)  # OMPL refuses seed 0
    ou.setLogLevel(ou.LogLevel.LOG_ERROR)
    xmin, ymin, xmax, ymax = world.map.boundary.bounds
    space = ob.RealVectorStateSpace(2)
    bounds = ob.RealVectorBounds(2)
    bounds.setLow(0, xmin)
    bounds.setLow(1, ymin)
    bounds.setHigh(0, xmax)
    bounds.setHigh(1, ymax)
    space.setBounds(bounds)
    ss = og.SimpleSetup(space)
    si = ss.getSpaceInformation()
    rows, x0, y0, inv = terrain.free_rows, terrain.x0_m, terrain.y0_m, 1.0 / terrain.cell_m
    n_rows, n_cols = terrain.shape

    def valid(state) -> bool:  # pure Python on list-of-lists: ~0.4 us per call
        i, j = int((state[1] - y0) * inv + 0.5), int((state[0] - x0) * inv + 0.5)
        return 0 <= i < n_rows and 0 <= j < n_cols and rows[i][j]

    ss.setStateValidityChecker(valid)
    return ss, si, space, valid


def roadmap_geometry(world, terrain, n_vertices: int, seed: int = 0,
                     max_neighbors: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Grow an OMPL PRM* roadmap over free space and copy it into numpy.

    Parameters
    ----------
    world : World (its boundary's bounding box is the sampling domain)
    terrain : TerrainRasters whose occupancy is the (approximate) validity checker
    n_vertices : milestones to grow
    seed : OMPL random seed (same seed, same roadmap)

    Returns
    -------
    xy_m : (n, 2) vertices [m]
    pairs : (p, 2) undirected edges i < j, unique; NOT yet checked exactly
    """
    from ompl import base as ob
    from ompl import geometric as og

    ss, si, _space, _valid = ompl_raster_setup(world, terrain, seed)  # held until return
    # Edges are re-checked exactly with shapely afterwards (0.3 s for 150k edges): OMPL only
    # needs to test the endpoints, which saves millions of Python validity calls.
    si.setStateValidityCheckingResolution(0.999)
    a, b = si.allocState(), si.allocState()
    home = world.home_xy_m
    a[0], a[1] = home
    b[0], b[1] = home
    ss.setStartAndGoalStates(a, b)  # PRM's setup needs a problem; it is never solved
    if max_neighbors is None:
        prm = og.PRMstar(si)
    else:
        prm = og.PRM(si)
        prm.setMaxNearestNeighbors(int(max_neighbors))
    ss.setPlanner(prm)
    ss.setup()
    prm.growRoadmapPtc(ob.PlannerTerminationCondition(lambda: prm.milestoneCount() >= n_vertices))
    data = ob.PlannerData(si)
    prm.getPlannerData(data)
    n = data.numVertices()
    xy = np.empty((n, 2))
    for i in range(n):
        s = data.getVertex(i).getState()
        xy[i, 0], xy[i, 1] = s[0], s[1]
    edges = [data.getEdges(i) for i in range(n)]
    src = np.repeat(np.arange(n), [len(e) for e in edges])
    dst = np.fromiter((j for e in edges for j in e), dtype=np.int64, count=len(src))
    # Only numpy leaves this function: no OMPL object or view outlives it (planner data or a
    # state read after its planner is gone is a use-after-free; one held by a module global
    # is reported as a leak at exit).
    lo, hi = np.minimum(src, dst), np.maximum(src, dst)
    key = np.unique((lo * n + hi)[lo != hi])  # one entry per undirected edge
    pairs = np.stack([key // n, key % n], axis=1)
    return xy, pairs


def connect_pairs(world, xy: np.ndarray, pairs: np.ndarray, exact: bool = True,
                  terrain=None) -> np.ndarray:
    """Keep the undirected edges whose straight segment lies in free space.

    ``exact`` uses ``World.segments_free`` (shapely); otherwise the occupancy raster.
    """
    if len(pairs) == 0:
        return pairs
    a, b = xy[pairs[:, 0]], xy[pairs[:, 1]]
    ok = world.segments_free(a, b) if exact else terrain.segments_free(a, b)
    return pairs[ok]


def attach_points(xy: np.ndarray, points: np.ndarray, k: int) -> np.ndarray:
    """Candidate undirected edges for new points (indices ``len(xy) + i``), shape (p, 2).

    Up to four new points (a start, a goal) are joined to their k nearest existing vertices
    and to each other; more points are joined to their k nearest among old and new vertices.
    """
    n, m = len(xy), len(points)
    new = n + np.arange(m)
    if m <= 4:
        k = min(k, n)
        _, nearest = cKDTree(xy).query(points, k=k)
        nearest = np.atleast_2d(nearest).reshape(m, k)
        pairs = [np.stack([np.repeat(new, k), nearest.ravel()], axis=1)]
        if m > 1:
            ii, jj = np.triu_indices(m, 1)
            pairs.append(np.stack([new[ii], new[jj]], axis=1))
        return np.concatenate(pairs).astype(np.int64)
    both = np.concatenate([xy, points])
    k = min(k + 1, len(both))
    _, nearest = cKDTree(both).query(points, k=k)
    pairs = np.stack([np.repeat(new, k), nearest.ravel()], axis=1)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    lo, hi = pairs.min(axis=1), pairs.max(axis=1)
    key = np.unique(lo * len(both) + hi)
    return np.stack([key // len(both), key % len(both)], axis=1).astype(np.int64)


def surface_samples(world, n: int, seed: int = 0) -> np.ndarray:
    """Up to ``n`` free points inside surfaces cheaper than default ground, by area [m].

    Uniform PRM* samples rarely land on a narrow cheap walkway; a few samples inside such
    surfaces let the roadmap follow them (the energy-optimal route often does).
    """
    cheap = [s for s in world.map.surfaces if s.crr < world.default_crr]
    if n <= 0 or not cheap:
        return np.empty((0, 2))
    rng = np.random.default_rng(seed)
    areas = np.array([s.polygon.area for s in cheap])
    counts = np.floor(n * areas / areas.sum()).astype(int)
    out = []
    for surface, count in zip(cheap, counts):
        if count == 0:  # a small surface among large ones gets no share of a small n
            continue
        x0, y0, x1, y1 = surface.polygon.bounds
        got, tries = [], 0
        while sum(len(g) for g in got) < count and tries < 20:
            tries += 1
            cand = rng.uniform([x0, y0], [x1, y1], (4 * count + 16, 2))
            inside = shapely.contains_xy(surface.polygon, cand[:, 0], cand[:, 1])
            cand = cand[inside & world.is_free(cand[:, 0], cand[:, 1])]
            got.append(cand)
        out.append(np.concatenate(got)[:count])
    return np.concatenate(out) if out else np.empty((0, 2))


def weigh(cost: EdgeCostContext, xy: np.ndarray, pairs: np.ndarray):
    """Directed edges (both ways) with energies and jacobians from undirected pairs."""
    if len(pairs) == 0:
        k = len(cost.model.theta) if cost.with_gradient else 0
        return (np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0), np.empty((0, k)))
    parts = [cost.costs(xy[chunk[:, 0]], xy[chunk[:, 1]])
             for chunk in np.array_split(pairs, -(-len(pairs) // WEIGH_CHUNK))]
    e_fwd, e_rev, j_fwd, j_rev = (np.concatenate(arrays) for arrays in zip(*parts))
    src = np.r_[pairs[:, 0], pairs[:, 1]]
    dst = np.r_[pairs[:, 1], pairs[:, 0]]
    return src, dst, np.r_[e_fwd, e_rev], np.concatenate([j_fwd, j_rev])


def build_roadmap(cost: EdgeCostContext, n_vertices: int = 5000, seed: int = 0,
                  extra_points=None, k_attach: int = 15, max_neighbors: int | None = None,
                  surface_fraction: float = 0.1) -> Roadmap:
    """Energy-weighted roadmap over a world, with home (and ``extra_points``) as vertices.

    Parameters
    ----------
    cost : model, world, terrain rasters, cruise speed, duty cycle, sensor rate
    n_vertices : vertices in all (PRM* milestones + surface samples); home comes on top
    seed : OMPL and numpy seed
    extra_points : (q, 2) points to add as vertices (e.g. the robot's position) [m]
    k_attach : nearest vertices each added point is connected to (collision-checked)
    max_neighbors : None: PRM* (k grows with log n); else PRM with this many neighbours
    surface_fraction : share of ``n_vertices`` sampled inside cheaper-than-default surfaces

    Raises
    ------
    InputError
        If ``n_vertices`` is outside the limits (``limits.check_roadmap_vertices``).
    """
    n_vertices = check_roadmap_vertices(n_vertices)
    extra = surface_samples(cost.world, int(surface_fraction * n_vertices), seed)
    xy, pairs = roadmap_geometry(cost.world, cost.terrain, n_vertices - len(extra), seed,
                                 max_neighbors)
    pairs = connect_pairs(cost.world, xy, pairs)
    roadmap = _from_pairs(cost, xy, pairs, home_index=-1)
    points = [np.asarray([cost.world.home_xy_m], float), extra]
    if extra_points is not None:
        points.append(np.atleast_2d(np.asarray(extra_points, float)))
    roadmap = add_vertices(cost, roadmap, np.concatenate(points), k_attach)
    return replace(roadmap, home_index=len(xy))


def _from_pairs(cost: EdgeCostContext, xy, pairs, home_index: int) -> Roadmap:
    src, dst, energy, jac = weigh(cost, xy, pairs)
    return Roadmap(xy, src, dst, energy, jac, float(cost.speed_mps), home_index)


def add_vertices(cost: EdgeCostContext, roadmap: Roadmap, points: np.ndarray,
                 k_attach: int = 15) -> Roadmap:
    """A roadmap with ``points`` appended as vertices ``n, n+1, ...``, each joined by exact
    collision-checked straight edges to its ``k_attach`` nearest vertices and to each other."""
    points = np.atleast_2d(np.asarray(points, float))
    pairs = attach_points(roadmap.xy_m, points, k_attach)
    xy = np.concatenate([roadmap.xy_m, points])
    pairs = connect_pairs(cost.world, xy, pairs)
    src, dst, energy, jac = weigh(cost, xy, pairs)
    return Roadmap(xy, np.r_[roadmap.src, src], np.r_[roadmap.dst, dst],
                   np.r_[roadmap.energy_J, energy], np.concatenate([roadmap.jacobian, jac]),
                   roadmap.speed_mps, roadmap.home_index)


@dataclass(frozen=True)
class EnergyField:
    """Minimum roadmap energy between every vertex and one source vertex.

    Attributes
    ----------
    source : the source vertex
    towards : True: energy from each vertex TO the source; False: FROM the source
    energy_J : per vertex [J]; inf where unreachable
    next_vertex : next vertex on the way to the source (towards) or the previous one on the
        way from it; -1 at the source and where unreachable
    gradient : d energy / d theta of each vertex's best path, (n, k) (reserve sizing)
    """

    source: int
    towards: bool
    energy_J: np.ndarray
    next_vertex: np.ndarray
    gradient: np.ndarray

    def path(self, vertex: int) -> list[int]:
        """Vertex sequence of the best path, oriented in the direction of travel."""
        if not np.isfinite(self.energy_J[vertex]):
            raise PlanningError(f"vertex {vertex} is not connected to vertex {self.source}")
        seq = walk_predecessors(self.next_vertex, self.source, vertex)
        return seq if self.towards else seq[::-1]


def walk_predecessors(pred: np.ndarray, source: int, vertex: int) -> list[int]:
    """Vertices from ``vertex`` to ``source`` along Dijkstra's predecessors ``pred`` (the
    vertex must be reached)."""
    seq = [int(vertex)]
    while seq[-1] != source:
        seq.append(int(pred[seq[-1]]))
    return seq


def energy_field(roadmap: Roadmap, source: int, towards: bool,
                 with_gradient: bool = True) -> EnergyField:
    """Dijkstra from (``towards=False``) or to (``towards=True``) a vertex, with gradients
    unless ``with_gradient`` is False (then, as for a roadmap without a jacobian, the field's
    gradient has no columns).

    Notes
    -----
    Energy to the source uses Dijkstra on the transposed graph: edge i -> j becomes j -> i,
    so the distance from the source there is the energy of reaching it here.
    """
    graph = roadmap.graph()
    if towards:
        graph = graph.T.tocsr()
    dist, pred = dijkstra(graph, directed=True, indices=source, return_predecessors=True)
    pred = np.where(pred < 0, -1, pred)
    gradient = np.zeros((roadmap.n_vertices, roadmap.jacobian.shape[1] if with_gradient else 0))
    reached = np.flatnonzero(np.isfinite(dist) & (pred >= 0))
    if len(reached) and gradient.shape[1]:
        index = roadmap.edge_index()
        order = reached[np.argsort(dist[reached], kind="stable")]
        a, b = (order, pred[order]) if towards else (pred[order], order)
        edge = np.asarray(index[a, b]).ravel() - 1
        step = roadmap.jacobian[edge]
        # Parents come before children in distance order (all weights > 0).
        for v, p, g in zip(order.tolist(), pred[order].tolist(), step):
            gradient[v] = gradient[p] + g
    return EnergyField(source, towards, dist, pred, gradient)
