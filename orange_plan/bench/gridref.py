"""Dense-grid Dijkstra: the brute-force reference the roadmap is checked against.

Nodes at the points of a regular grid in free space, 8- or 16-connected, every edge tested
exactly (shapely) and costed with the scenario's EnergyModel on exact terrain in both
directions (``physics.pathcost``). Slow but simple: for benchmarks and tests only.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from orange_plan.errors import InputError
from orange_plan.planning.roadmap import MIN_EDGE_J, EdgeCostContext

OFFSETS_8 = [(1, 0), (0, 1), (1, 1), (1, -1)]
OFFSETS_16 = [*OFFSETS_8, (1, 2), (2, 1), (2, -1), (1, -2)]


@dataclass(frozen=True)
class GridGraph:
    """A grid graph with directed energy weights.

    Attributes
    ----------
    xy_m : node positions (only free nodes), (n, 2) [m]
    graph : sparse (n, n) matrix of directed edge energies [J]
    """

    xy_m: np.ndarray
    graph: csr_matrix

    def nearest(self, xy) -> int:
        """Index of the node nearest to a point."""
        return int(np.argmin(np.hypot(*(self.xy_m - np.asarray(xy, float)).T)))

    def energies_from(self, xy) -> np.ndarray:
        """Minimum grid energy from the node nearest ``xy`` to every node [J]."""
        return dijkstra(self.graph, indices=self.nearest(xy))

    def energies_to(self, xy) -> np.ndarray:
        """Minimum grid energy from every node to the node nearest ``xy`` [J]."""
        return dijkstra(self.graph.T.tocsr(), indices=self.nearest(xy))

    def path(self, start_xy, goal_xy) -> np.ndarray:
        """Node polyline of the minimum-energy grid path, (m, 2) [m]."""
        s, g = self.nearest(start_xy), self.nearest(goal_xy)
        dist, pred = dijkstra(self.graph, indices=s, return_predecessors=True)
        if not np.isfinite(dist[g]):
            raise InputError("the two points are not connected on the grid")
        seq = [g]
        while seq[-1] != s:
            seq.append(int(pred[seq[-1]]))
        return self.xy_m[seq[::-1]]


def grid_graph(cost: EdgeCostContext, cell_m: float, connectivity: int = 16,
               origin_xy=None) -> GridGraph:
    """Build the dense grid over the world's boundary box.

    Parameters
    ----------
    cost : edge costs (use exact terrain for a reference)
    cell_m : grid spacing [m]
    connectivity : 8 or 16
    origin_xy : a point the grid passes through (default: the boundary's lower-left corner)
    """
    if connectivity not in (8, 16):
        raise InputError(f"connectivity = {connectivity} must be 8 or 16")
    world = cost.world
    xmin, ymin, xmax, ymax = world.map.boundary.bounds
    ox, oy = (xmin, ymin) if origin_xy is None else origin_xy
    xs = ox + cell_m * np.arange(np.ceil((xmin - ox) / cell_m), np.floor((xmax - ox) / cell_m) + 1)
    ys = oy + cell_m * np.arange(np.ceil((ymin - oy) / cell_m), np.floor((ymax - oy) / cell_m) + 1)
    gx, gy = np.meshgrid(xs, ys)
    rows, cols = gx.shape
    free = world.is_free(gx, gy)
    index = np.full(gx.shape, -1)
    index[free] = np.arange(int(free.sum()))
    src, dst = [], []
    offsets = OFFSETS_16 if connectivity == 16 else OFFSETS_8
    for dj, di in offsets:
        i0, i1 = max(0, -di), rows - max(0, di)
        j0, j1 = max(0, -dj), cols - max(0, dj)
        a = index[i0:i1, j0:j1]
        b = index[i0 + di:i1 + di, j0 + dj:j1 + dj]
        both = (a >= 0) & (b >= 0)
        src.append(a[both])
        dst.append(b[both])
    src, dst = np.concatenate(src), np.concatenate(dst)
    xy = np.stack([gx[free], gy[free]], axis=1)
    ok = world.segments_free(xy[src], xy[dst])
    src, dst = src[ok], dst[ok]
    e_fwd, e_rev, _, _ = replace(cost, with_gradient=False).costs(xy[src], xy[dst])
    w = np.maximum(np.r_[e_fwd, e_rev], MIN_EDGE_J)
    n = len(xy)
    graph = csr_matrix((w, (np.r_[src, dst], np.r_[dst, src])), shape=(n, n))
    return GridGraph(xy, graph)
