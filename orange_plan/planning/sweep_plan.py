"""Complete sweeps as plans: the best sweep, its guaranteed prefix and its continuation.

``sweep_tour`` takes the complete sweep (``planning.sweeps``) expected to sense most before a
closed loop turns it home, checks its prefix up to the open-loop turn exactly like any tour
(``walk.evaluate_walk``: energies, returns and reserves at every vertex), bisects that
prefix's length until every margin is >= 0 with little slack (``_guaranteed_prefix``) and
keeps the rest of the sweep as the plan's continuation (``route_after``): the route a robot
that measures its energy flies on, turning home on the live check (docs/coverage-patterns.md).
"""

from __future__ import annotations

import contextlib
import functools
from dataclasses import replace

import numpy as np

from orange_plan.errors import PlanningError
from orange_plan.planning.paths import cut_path
from orange_plan.planning.plan import Plan, StartState
from orange_plan.planning.reserve import closed_loop_return_spread
from orange_plan.planning.roadmap import add_vertices, energy_field
from orange_plan.planning.walk import (
    TourSetup,
    _finish,
    _per_metre,
    _time_left_s,
    drivable_m,
    driven_energy_J,
    evaluate_walk,
)


def sweep_tour(ctx, setup: TourSetup, start: StartState, *, t0: float,
               optimise_speed: bool = True, baseline: bool = True) -> Plan | None:
    """The best complete sweep (``planning.sweeps``) as a plan, or None.

    The sweep is chosen by what it senses before the closed-loop rule turns it home; its
    prefix up to the open-loop turn is then checked exactly like any tour (``evaluate_walk``:
    energies, returns and reserves at every vertex), its length bisected until every margin
    is >= 0 with little slack (``_guaranteed_prefix``), and the rest of the sweep becomes
    the plan's ``continuation_xy_m``: the route a robot that measures its energy flies on,
    turning home on the live check. ``baseline``: the lawnmower's own route
    (``lawnmower.plan_lawnmower``) is among the sweeps scored, so the plan senses at least
    as much as the lawnmower under the same rule. None for a start away from home or with
    area already sensed (a replan), or when no sweep keeps the way home.
    """
    from orange_plan.planning.homepaths import HomePaths
    from orange_plan.planning.lawnmower import Detours, SweepLanes, plan_lawnmower
    from orange_plan.planning.sweeps import best_sweep, score_route, score_step_m

    reach = setup.reach
    home_xy = np.asarray(reach.home_xy_m, float)
    at_home = start.xy_m is None or np.hypot(*(np.asarray(start.xy_m, float) - home_xy)) < 1e-6
    if not at_home or start.covered is not None:
        return None
    e_left = reach.energy_available_J - reach.energy_used_J
    time_left = _time_left_s(ctx, start)
    home = HomePaths(reach).calibrate(functools.partial(driven_energy_J, reach.exact))
    rm = reach.roadmap
    detours = Detours(ctx.world, rm.xy_m, rm.src, rm.dst)
    lanes = SweepLanes(ctx.world, setup.grid, ctx.scenario.mission.sensor_radius_m)
    baseline_xy = None
    # no lawnmower joins up on some roadmaps: the other sweeps still may
    with contextlib.suppress(PlanningError):
        baseline_xy = plan_lawnmower(ctx, reach, lanes=lanes).xy_m if baseline else None
    longest = 1.05 * drivable_m(ctx, reach, time_left)
    # chosen under the rule that flies it: a closed loop keeps for its way home the floor of
    # the a-priori discrepancy (``RETURN_SPREAD_FLOOR``), not all of it; scored with all of
    # it, sweeps whose returns are short look better than they fly
    flown = replace(ctx, model=ctx.model.with_discrepancy(closed_loop_return_spread(ctx.model)))
    # scored over the budgets a run flies on: its energy differs from the model's by the
    # a-priori run-to-run discrepancy (the floor above only sizes the return's reserve)
    sweep = best_sweep(flown, reach, home, setup.grid, detours, baseline_xy, e_left, time_left,
                       longest, lanes=lanes, run_sd=ctx.model.discrepancy_rel_sd)
    if sweep is None:
        return None
    # the guaranteed prefix is sought from its turn points on the scenario's model; the
    # closed loop's own (the summary's expectation) are the ones it was chosen by
    opened = score_route(ctx, reach.fast, home, setup.grid, sweep.xy_m, e_left, time_left,
                         score_step_m(ctx), longest, reach.reserve)
    checked = _guaranteed_prefix(ctx, setup, start, sweep.xy_m, opened.open_s_m,
                                 opened.closed_s_m, time_left, optimise_speed)
    if checked is None:
        return None
    walk_setup, plan, variance, cut_m = checked
    plan = _finish(ctx, walk_setup, plan, plan.xy_m[1:-1], variance, start, t0)
    closed_m2 = max(sweep.score.closed_m2, plan.summary["coverage_m2"])
    summary = {**plan.summary,
               "pattern": sweep.pattern,
               "sweeps_scored": sweep.tried,
               "guaranteed_length_m": cut_m,
               "closed_loop_turn_m": max(sweep.score.closed_s_m, cut_m),
               "closed_loop_coverage_m2": closed_m2,
               "closed_loop_speed_mps": float(reach.exact.speed_mps),
               "sweep_length_m": sweep.score.length_m,
               # what it is expected to sense if the run's energy is not the model's
               "closed_loop_spread_m2": [
                   [f, float(m2)] for f, m2 in zip(sweep.spread_factors, sweep.spread_m2)]}
    return replace(plan, summary=summary, continuation_xy_m=route_after(sweep.xy_m, cut_m))


PREFIX_TRIES = 9
"""Exact checks of a sweep prefix's length (a bisection started at the scored guess)."""


def _guaranteed_prefix(ctx, setup: TourSetup, start: StartState, route, guess_m: float,
                       upper_m: float, time_left: float, optimise_speed: bool):
    """The longest prefix of ``route`` whose walk home keeps every margin >= 0 and the time
    limit, found by bisection on the exact check between 0 and ``upper_m`` (the closed-loop
    turn: no open-loop prefix goes farther), starting at ``guess_m``: (walk setup, plan,
    variance, length [m]) or None when no prefix fits."""
    per_m = _per_metre(ctx.model, ctx)
    lo, hi, best = 0.0, max(upper_m, guess_m), None
    cut_m = guess_m if 0 < guess_m < hi else 0.5 * hi
    for _ in range(PREFIX_TRIES):
        if cut_m <= 0 or hi - lo <= 0.01 * hi:
            break
        walk = _walk_along(setup, cut_path(route, cut_m))
        fits = False
        if walk is not None:
            walk_setup, ids = walk
            plan, variance = evaluate_walk(ctx, walk_setup, ids, start, optimise_speed)
            slack = float(plan.margin_J.min())
            fits = slack >= 0 and float(plan.t_s[-1]) - start.time_s <= time_left
        if fits:
            lo, best = cut_m, (walk_setup, plan, variance, cut_m)
            if slack < 1e-3 * per_m * max(cut_m, 1.0):
                break
            cut_m = min(0.5 * (lo + hi), cut_m + slack / per_m)
        else:
            hi = cut_m
            cut_m = 0.5 * (lo + hi)
    return best


def _walk_along(setup: TourSetup, prefix_xy):
    """``prefix_xy`` (from home) as roadmap vertices, then the roadmap's way home:
    (setup with the extended roadmap and to-home field, walk vertex ids), or None when a
    prefix vertex cannot be joined to the roadmap."""
    pts = np.asarray(prefix_xy, float)[1:]
    if len(pts) == 0:
        return None
    roadmap = add_vertices(setup.reach.fast, setup.roadmap, pts)
    new = setup.roadmap.n_vertices + np.arange(len(pts))
    to_home = energy_field(roadmap, roadmap.home_index, towards=True)
    if not np.all(np.isfinite(to_home.energy_J[new])):
        return None
    back = to_home.path(int(new[-1]))
    ids = np.r_[roadmap.home_index, new, back[1:]].astype(int)
    return replace(setup, roadmap=roadmap, to_home=to_home), ids


def route_after(route, s_m: float) -> np.ndarray:
    """The part of a polyline after arclength ``s_m`` (the cut point first) [m]."""
    route = np.asarray(route, float)
    total = float(np.sum(np.hypot(*np.diff(route, axis=0).T)))
    return cut_path(route[::-1], max(total - s_m, 0.0))[::-1]
