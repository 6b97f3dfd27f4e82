"""Property: reach never calls a goal feasible whose round trip does not fit.

Small random maps (random boxes, a random hill or ramp, a random slow surface) are solved by
the roadmap and by a brute-force 16-connected grid Dijkstra on the same EnergyModel
(``bench.gridref``, edges costed with ``pathcost`` on exact terrain). The energy used so
far is set so that about half of the goals fit.

Why the invariant is stated this way: the grid is itself only an upper bound of the best
path, and not a tight one under the no-recovery clip (on a slope, a straight descending line
gets its rolling resistance paid by gravity while a grid path of flat and steeper pieces does
not: a measured case had the grid 10 % above a straight roadmap edge). So a roadmap path may
legitimately be cheaper than the grid's. What must hold is that every feasible goal comes
with a drivable round trip (exact collision test) whose exact energy (``path_energy``) is the
one reported and fits with the reserve; then the best true round trip, at most
min(grid, roadmap path), fits as well.

The other way round, reach must not lose goals: of the goals whose grid round trip fits
with ``SLACK`` of its energy to spare, at most ``MISSED_MAX`` (over all examples, drawn
deterministically so the bound cannot flake) may be called infeasible.
"""

from __future__ import annotations

import multiprocessing
import tempfile
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from planning_worlds import draw_world_spec, write_world

from orange_plan.bench.gridref import grid_graph
from orange_plan.context import load_context
from orange_plan.physics.pathcost import path_energy
from orange_plan.planning.reach import prepare_reach, query_goals

GRID_M = 2.0


@st.composite
def worlds(draw):
    spec = draw_world_spec(draw)
    w, h = spec["width_m"], spec["height_m"]
    goals = draw(st.lists(st.tuples(st.integers(0, int(w / 2)), st.integers(0, int(h / 2))),
                          min_size=4, max_size=8, unique=True))
    return spec, [(GRID_M * i, GRID_M * j) for i, j in goals]


SLACK = 0.10
"""A goal is clearly feasible when its grid round trip fits with this share of its energy to
spare (closer calls go either way: the roadmap's path may be a little dearer or cheaper)."""
MISSED_MAX = 0.15
"""At most this fraction of the clearly feasible goals may reach call infeasible (its
300-vertex roadmap can miss a narrow way the 16-connected grid takes; measured over 60 random
examples: 7 of 121 (6 %), 5 of 117 with 1000 vertices)."""


def _clear_and_missed(folder: str) -> dict:
    """Every drawn example checked in this process (worlds written under ``folder``); the
    tally of clearly feasible goals and of those reach called infeasible."""
    tally = {"clear": 0, "missed": 0}

    @settings(max_examples=25, deadline=None, database=None, derandomize=True,
              suppress_health_check=[HealthCheck.too_slow])
    @given(case=worlds(), seed=st.integers(0, 1000))
    def check(case, seed):
        spec, goals = case
        ctx = load_context(write_world(Path(tempfile.mkdtemp(dir=folder)), **spec))
        reach = prepare_reach(ctx, n_vertices=300, seed=seed)
        world, exact = ctx.world, reach.exact
        grid = grid_graph(exact, GRID_M, 16, origin_xy=(0.0, 0.0))
        truth = grid.energies_from(world.home_xy_m) + grid.energies_to(world.home_xy_m)
        goal_xy = np.array(goals)
        truth_trip = np.array([truth[grid.nearest(g)] if world.is_free(*g) else np.inf
                               for g in goal_xy])
        reserve = 0.1 * reach.energy_available_J
        finite = truth_trip[np.isfinite(truth_trip)]
        used = 0.0
        if len(finite):
            used = float(np.clip(reach.energy_available_J - reserve - np.median(finite), 0,
                                 reach.energy_available_J))
        reach = replace(reach, energy_used_J=used)

        for g, true_J in zip(query_goals(reach, goal_xy), truth_trip):
            if g.valid and used + (1 + SLACK) * true_J + reserve <= reach.energy_available_J:
                tally["clear"] += 1
                tally["missed"] += not g.feasible
            if not g.valid:
                assert not world.is_free(g.x_m, g.y_m) and not g.feasible
                continue
            event(f"goal feasible: {g.feasible}")
            if not g.feasible:
                continue
            trip = g.path_xy_m
            assert world.segments_free(trip[:-1], trip[1:]).all()
            exact_J = path_energy(ctx.model, world, trip, exact.speed_mps, exact.conditions,
                                  exact.accel_max_mps2).total_J
            reported = g.energy_to_goal_J + g.energy_goal_to_home_J
            assert reported == pytest.approx(exact_J, rel=1e-9)
            assert used + exact_J + g.reserve_J <= reach.energy_available_J
            assert g.reserve_J == pytest.approx(reserve)
            # The robot's best option costs at most min(grid truth, roadmap path): it fits too.
            assert used + min(true_J, exact_J) + reserve <= reach.energy_available_J

    check()
    return tally


@pytest.mark.timeout(240)
def test_feasible_goals_fit_match_exact_energy_and_few_are_missed(tmp_path):
    """Counted in a fresh process: OMPL takes a random seed only before the first random
    number of its process, so in a test worker each roadmap depends on what ran there before
    (the same examples missed 11 of 60 goals after other tests, 9 or fewer alone)."""
    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(1, mp_context=spawn) as pool:
        tally = pool.submit(_clear_and_missed, str(tmp_path)).result()
    assert tally["clear"] >= 30, tally
    assert tally["missed"] <= MISSED_MAX * tally["clear"], tally
