"""Benchmark of the planning core (``orange-plan bench reach``): timings and path quality.

Measures, on one scenario (default: the hilly campus example), its targets:
roadmap + weights + both fields at 5,000 vertices; 10,000 goal queries; point-to-point energy
against a dense-grid Dijkstra reference on the same map and model; energy saved against the
shortest path; speed-optimiser time at N = 50, 200, 1000. Timings are medians over repeats.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from orange_plan.bench.gridref import grid_graph
from orange_plan.planning.paths import bitstar_path, evaluate_path, roadmap_path
from orange_plan.planning.reach import prepare_reach, query_points
from orange_plan.planning.speed import SpeedSolver, cut_path, speed_problem

if TYPE_CHECKING:
    from orange_plan.context import Context

DEFAULT_PAIRS = ((0.075, 0.5, 0.925, 0.5), (0.075, 0.5, 0.875, 0.875),
                 (0.5, 0.0625, 0.5, 0.9375), (0.075, 0.5, 0.5625, 0.375))
"""Start/goal pairs as fractions of the boundary box (x0, y0, x1, y1)."""


@dataclass(frozen=True)
class PairResult:
    """One start/goal pair: exact energies of each method's path [J]."""

    start_xy_m: tuple[float, float]
    goal_xy_m: tuple[float, float]
    grid_J: float
    roadmap_J: float
    shortest_J: float
    bitstar_J: float | None

    @property
    def roadmap_vs_grid(self) -> float:
        return self.roadmap_J / self.grid_J

    @property
    def saving_vs_shortest(self) -> float:
        return 1.0 - self.roadmap_J / self.shortest_J


@dataclass(frozen=True)
class BenchResult:
    """Medians over repeats (seconds) and path-quality figures."""

    scenario: str
    repeats: int
    n_vertices: int
    n_edges: int
    roadmap_s: float
    goal_queries: int
    queries_s: float
    grid_cell_m: float
    grid_s: float
    pairs: list[PairResult]
    bitstar_seconds: float
    speed_s: dict = field(default_factory=dict)  # N -> {"cold_s", "warm_s", "iterations"}

    def to_dict(self) -> dict:
        d = asdict(self)
        for p, pr in zip(d["pairs"], self.pairs):
            p["roadmap_vs_grid"] = pr.roadmap_vs_grid
            p["saving_vs_shortest"] = pr.saving_vs_shortest
        return d


def _median_time(fn: Callable[[], object], repeats: int):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def run_reach_bench(ctx: Context, repeats: int = 3, n_vertices: int = 5000, n_queries: int = 10_000,
                    grid_cell_m: float | None = None, bitstar_seconds: float = 1.0,
                    speed_sizes=(50, 200, 1000), pairs=DEFAULT_PAIRS,
                    step: Callable[[str], None] = lambda s: None) -> BenchResult:
    """Run the benchmark; ``step`` receives progress descriptions."""
    step(f"roadmap + weights + fields ({n_vertices} vertices) x {repeats}")
    roadmap_s, reach = _median_time(lambda: prepare_reach(ctx, n_vertices=n_vertices), repeats)

    rng = np.random.default_rng(0)
    xmin, ymin, xmax, ymax = ctx.world.map.boundary.bounds
    points = rng.uniform([xmin, ymin], [xmax, ymax], (n_queries, 2))
    step(f"{n_queries} goal queries x {repeats}")
    query_points(reach, points[:10])  # warm caches (KD-tree code paths)
    queries_s, _ = _median_time(lambda: query_points(reach, points), repeats)

    dem = ctx.world.map.elevation
    cell = grid_cell_m or (dem.cell_m if dem is not None else max(xmax - xmin, ymax - ymin) / 160)
    results = []
    step(f"dense-grid reference ({cell:g} m, 16-connected)")
    t0 = time.perf_counter()
    grid = grid_graph(reach.exact, cell, 16, origin_xy=(xmin, ymin))
    grid_s = time.perf_counter() - t0
    for fx0, fy0, fx1, fy1 in pairs:
        a = _snap(grid, (xmin + fx0 * (xmax - xmin), ymin + fy0 * (ymax - ymin)))
        b = _snap(grid, (xmin + fx1 * (xmax - xmin), ymin + fy1 * (ymax - ymin)))
        step(f"paths {a} -> {b}")
        ref = evaluate_path(reach.exact, grid.path(a, b), "grid")
        best = roadmap_path(reach.exact, reach.roadmap, a, b)
        short = roadmap_path(reach.exact, reach.roadmap, a, b, weight="length")
        bit = bitstar_path(reach.fast, reach.exact, a, b, bitstar_seconds) if bitstar_seconds else None
        results.append(PairResult(a, b, ref.energy_J, best.energy_J, short.energy_J,
                                  None if bit is None else bit.energy_J))

    speed = {}
    a, b = results[0].start_xy_m, results[0].goal_xy_m
    path = roadmap_path(reach.exact, reach.roadmap, a, b).xy_m
    for n in speed_sizes:
        step(f"speed profile N = {n}")
        solver = SpeedSolver(ctx.model)
        pieces = cut_path(ctx.world, path, max(n, len(path) - 1))
        problem = speed_problem(ctx, pieces)
        t0 = time.perf_counter()
        solver.solve(problem)
        cold = time.perf_counter() - t0
        warm, prof = _median_time(lambda s=solver, p=problem: s.solve(p), repeats)
        speed[int(n)] = {"cold_s": cold, "warm_s": warm, "iterations": prof.iterations}
    return BenchResult(ctx.scenario.name, repeats, reach.roadmap.n_vertices,
                       len(reach.roadmap.src), roadmap_s, n_queries, queries_s, cell, grid_s,
                       results, bitstar_seconds, speed)


def _snap(grid, xy) -> tuple[float, float]:
    """The grid node nearest a point (pairs start and end on the reference grid)."""
    return tuple(float(v) for v in grid.xy_m[grid.nearest(xy)])
