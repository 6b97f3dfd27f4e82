"""Ways home from any point: the roadmap's minimum-energy tree, joined by a straight segment.

What a homing rule reads in flight, many times a second: the length, time and energy of the
return from the robot's position, and the predictive variance of that energy (for a reserve
that covers the uncertainty of the return only). The return is the to-home energy field's
path from the visible roadmap vertex that minimises ``e_per_m |p - v| + E_home(v)``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from orange_plan.errors import PlanningError
from orange_plan.physics.range import flat_energy_per_m_J
from orange_plan.planning.lawnmower import FreeSegments
from orange_plan.planning.paths import clean_polyline


class HomePaths:
    """Return paths home from any point: the roadmap's minimum-energy tree, joined straight.

    A point joins the visible roadmap vertex (of its ``k`` nearest, and home) minimising
    ``e_per_m |p - v| + E_home(v)``; the return path is ``p -> v -> ... -> home`` along the
    to-home energy field, its length the sum of the tree's edges.
    """

    def __init__(self, reach, k: int = 10):
        self.segments_free = FreeSegments(reach.exact.world)
        rm, field = reach.roadmap, reach.to_home
        self.xy, self.home = rm.xy_m, rm.home_index
        self.next, self.energy = field.next_vertex, field.energy_J
        self.gradient = np.asarray(field.gradient, float).reshape(len(self.energy), -1)
        self.k = min(k, rm.n_vertices)
        self.tree = cKDTree(self.xy)
        self.speed_mps = float(reach.exact.speed_mps)
        self.e_per_m = _flat_energy_per_m(reach.exact)
        self.length_home = self._tree_lengths()
        self.scale, self.overhead_J = 1.0, 0.0

    def calibrate(self, driven_energy_J, samples: int = 24, seed: int = 0) -> HomePaths:
        """Fit the field's energies to returns as driven (``driven_energy_J(xy)``: e.g.
        ``tour.drive`` on exact costs, with ramps, stops and the final wait at home, which the
        roadmap's steady per-metre energies leave out) on ``samples`` random reachable
        vertices: ``E = scale E_field +
        overhead``, the overhead raised by the largest positive residual so no sample is
        underestimated. A short return is dominated by that overhead (twice the field's
        figure on a 13 m return of the small random map). Returns self."""
        rng = np.random.default_rng(seed)
        reached = np.flatnonzero(np.isfinite(self.energy) & (self.length_home > 0))
        if reached.size == 0:
            return self
        picks = rng.choice(reached, size=min(samples, reached.size), replace=False)
        field, driven = [], []
        for v in picks:
            seq = [int(v)]
            while seq[-1] != self.home:
                seq.append(int(self.next[seq[-1]]))
            xy = clean_polyline(self.xy[seq])
            if len(xy) < 2:
                continue
            field.append(self.energy[v])
            driven.append(float(driven_energy_J(xy)))
        if len(field) < 2:
            return self
        field, driven = np.asarray(field), np.asarray(driven)
        scale, overhead = np.polyfit(field, driven, 1)
        scale = max(float(scale), 1.0)
        overhead = float(np.max(driven - scale * field))
        self.scale, self.overhead_J = scale, max(overhead, 0.0)
        return self

    def _tree_lengths(self) -> np.ndarray:
        length = np.full(len(self.xy), np.inf)
        length[self.home] = 0.0
        reached = np.flatnonzero(np.isfinite(self.energy))
        for v in reached[np.argsort(self.energy[reached], kind="stable")]:
            nxt = self.next[v]
            if v != self.home and nxt >= 0:
                length[v] = length[nxt] + float(np.hypot(*(self.xy[v] - self.xy[nxt])))
        return length

    def _join(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Chosen vertex and its join length for each point (vertex -1: none visible)."""
        pts = np.atleast_2d(np.asarray(points, float))
        n = len(pts)
        _, near = self.tree.query(pts, k=self.k)
        cand = np.c_[near.reshape(n, self.k), np.full(n, self.home)]
        a = np.repeat(pts, cand.shape[1], axis=0)
        b = self.xy[cand.ravel()]
        d = np.hypot(*(b - a).T).reshape(cand.shape)
        ok = self.segments_free(a, b).reshape(cand.shape) | (d < 1e-9)
        score = np.where(ok, self.e_per_m * d + self.energy[cand], np.inf)
        best = np.argmin(score, axis=1)
        rows = np.arange(n)
        v = np.where(np.isfinite(score[rows, best]), cand[rows, best], -1)
        return v, d[rows, best]

    def length_m(self, points) -> np.ndarray:
        """Length of the return path from each point [m] (inf where none is found)."""
        v, d = self._join(points)
        return np.where(v >= 0, d + self.length_home[np.maximum(v, 0)], np.inf)

    def time_s(self, points) -> np.ndarray:
        """Return path length over the cruise speed [s] (PX4's ``time_estimate``)."""
        return self.length_m(points) / self.speed_mps

    def returns(self, points, model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Energy [J], its predictive variance [J^2] and length [m] of the return from each
        point (inf where none is found), from one join.

        The energy is the field's, fitted to driven returns when ``calibrate`` was called.
        The variance is ``model.predictive_variance_J2`` of the joined vertex's field
        gradient scaled to the return's energy (the join is a few metres of the same
        physics), so a confidence reserve on it covers the uncertainty of the return alone.
        """
        v, d = self._join(points)
        ok = v >= 0
        at = np.maximum(v, 0)
        field = self.e_per_m * d + self.energy[at]
        energy = np.where(ok, self.scale * field + self.overhead_J, np.inf)
        length = np.where(ok, d + self.length_home[at], np.inf)
        if self.gradient.shape[1] == 0:
            var = (model.discrepancy_rel_sd * energy) ** 2
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                scale = np.where(ok & (self.energy[at] > 0), energy / self.energy[at], 1.0)
            var = model.predictive_variance_J2(self.gradient[at] * scale[:, None],
                                               np.where(ok, energy, 0.0))
        return energy, np.where(ok, var, np.inf), length

    def path(self, point) -> np.ndarray:
        """Vertices of the return path from ``point`` to home [m]."""
        p = np.asarray(point, float).reshape(2)
        v, _ = self._join(p[None])
        v = int(v[0])
        if v < 0:
            raise PlanningError(f"no return path home from ({p[0]:g}, {p[1]:g})")
        seq = [v]
        while seq[-1] != self.home:
            seq.append(int(self.next[seq[-1]]))
        return clean_polyline(np.vstack([p, self.xy[seq]]))


def _flat_energy_per_m(cost) -> float:
    """Energy per metre at the cruise speed on flat default ground [J/m] (joins' weight)."""

    return float(flat_energy_per_m_J(cost.model, cost.speed_mps, cost.world.default_crr,
                                     cost.conditions.sensor_rate_Hz, cost.conditions.duty_cycle,
                                     cost.conditions.elapsed_s))
