"""Replanning speed: how long a mid-mission replan takes (target: p95 <= 250 ms on
the hilly campus example).

A cold plan is made from home (roadmap, candidates, leg matrices, search, exact check); then
``n`` replans start from states spread along it (position, energy used, time, covered area so
far), each with a model whose coefficients are drawn from the scenario's covariance (what the
online estimator hands the planner mid-mission). Every replan is the session's own path
(``TourPlanner.plan``: warm, on the first plan's roadmap) and is checked like any plan: it
starts at the robot, ends at home and keeps every margin >= 0. Near the end of the first
plan a replan may find that no new candidate fits any more (the robot should head home): that
answer is timed like the others and counted in ``nothing_fits``.

Besides wall-clock times the bench reports each replan's CPU time (``time.process_time``):
on a shared machine the wall-clock p95 follows the other processes' load, the CPU time much
less, so the two together tell a slow replan from a busy machine; the load average
(``os.getloadavg``, 1/5/15 min) before and after is reported with them.
"""

from __future__ import annotations

import os
import statistics
import time
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np

from orange_plan.errors import InputError
from orange_plan.planning.plan import StartState
from orange_plan.planning.tour import TourPlanner

if TYPE_CHECKING:
    from orange_plan.context import Context

TARGET_P95_S = 0.25


@dataclass(frozen=True)
class ReplanBench:
    """Timings [s] and checks of ``run_replan_bench``."""

    scenario: str
    cold_s: float
    replans: int
    median_s: float
    p95_s: float
    max_s: float
    all_safe: bool
    nothing_fits: int = 0
    cpu_median_s: float = 0.0
    cpu_p95_s: float = 0.0
    load_before: tuple = ()
    load_after: tuple = ()
    target_p95_s: float = TARGET_P95_S

    def to_dict(self) -> dict:
        return asdict(self) | {"p95_vs_target": self.p95_s / self.target_p95_s}


def run_replan_bench(ctx: Context, n_replans: int = 40, n_vertices: int = 5000, seed: int = 0,
                     tick=None) -> ReplanBench:
    """Cold plan, then ``n_replans`` warm replans from states along it (see module doc)."""
    load_before = os.getloadavg()
    rng = np.random.default_rng(seed)
    planner = TourPlanner(ctx, n_vertices=n_vertices, seed=seed, bitstar_legs=0)
    t0 = time.perf_counter()
    plan = planner.plan()
    cold = time.perf_counter() - t0
    times, cpu, safe, nothing_fits = [], [], True, 0
    for k in range(n_replans):
        i = int((k + 0.5) / n_replans * (len(plan.xy_m) - 1))
        start = StartState(tuple(plan.xy_m[i]), float(plan.energy_used_J[i]),
                           float(plan.t_s[i]), None)
        model = _drawn_model(ctx.model, rng)
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            again = planner.plan(start, model=model)
        except InputError:  # no candidate fits: the answer is "go home"
            again = None
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        if again is None:
            nothing_fits += 1
        else:
            safe &= bool(np.all(again.margin_J >= 0) and np.allclose(again.xy_m[0], start.xy_m)
                         and np.allclose(again.xy_m[-1], ctx.world.home_xy_m))
        if tick:
            tick()
    times = np.asarray(times)
    return ReplanBench(ctx.scenario.name, cold, n_replans, float(statistics.median(times)),
                       float(np.percentile(times, 95)), float(times.max()), safe, nothing_fits,
                       float(statistics.median(cpu)), float(np.percentile(cpu, 95)),
                       load_before, os.getloadavg())


def _drawn_model(model, rng):
    """The model with coefficients drawn from its covariance (kept positive)."""
    theta = rng.multivariate_normal(model.theta, model.cov)
    theta = np.where(model.theta > 0, np.maximum(theta, 0.1 * model.theta), theta)
    return model.with_theta(dict(zip(model.names, theta)))
