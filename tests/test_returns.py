"""The returns home kept across replans (planning.returns) and the compiled kinematics give the
energies the interpreted drive gave, path by path.

Reference: each return driven alone by the interpreted ``Driver`` as it was before its loop
was compiled (tests/driver_reference.py), its samples turned into a MotionState and summed
through the model, with no store and no batching.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from driver_reference import ReferenceDriver
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from planning_worlds import write_world

from orange_plan.context import load_context
from orange_plan.physics.conditions import Conditions
from orange_plan.physics.pathcost import subdivide
from orange_plan.physics.profile import (
    SAMPLE_DT_S,
    TURN_SPREAD_S,
    Driver,
    drive_state,
    driven_energies_and_gradients,
    spread_yaw_rate,
    step_headings_rad,
)
from orange_plan.planning.reach import cost_contexts
from orange_plan.planning.returns import DrivenReturns
from orange_plan.world.rasters import build_rasters

WIDTH_M, HEIGHT_M = 120.0, 90.0


@pytest.fixture(scope="module")
def ctx(tmp_path_factory):
    """A hill, a ramp, a slow strip, turning costs and a wind, with inertia and regen."""
    folder = tmp_path_factory.mktemp("returns")
    return load_context(write_world(folder, width_m=WIDTH_M, height_m=HEIGHT_M,
                                    hill=(50.0, 40.0, 8.0, 15.0), ramp=0.02, turn=6.0,
                                    drag=0.4, surfaces=[(80.0, 0.0, 100.0, HEIGHT_M, 0.12)],
                                    wind=(2.5, 200.0), terms=("inertia", "regen")))


def reference_return(cost, xy):
    """Energy [J] and gradient of driving ``xy`` from rest to rest, the interpreted way."""
    steps = subdivide(cost.world, xy[:-1], xy[1:])
    edges = np.r_[0.0, np.cumsum(steps.horiz_m)]
    driver = ReferenceDriver(edges, steps.per_step(np.full(steps.n_segments, cost.speed_mps)),
                             steps.cos_t, cost.accel_max_mps2, SAMPLE_DT_S,
                             cost.conditions.duty_cycle)
    kin = driver.run(10**7)
    assert driver.finished
    heading = step_headings_rad(steps)[kin["step"]]
    yaw, _ = spread_yaw_rate(heading, heading[0], np.zeros(0),
                             round(TURN_SPREAD_S / SAMPLE_DT_S), SAMPLE_DT_S)
    c = cost.conditions
    state = drive_state(steps, kin, yaw, c.wind_xy_mps, steps.crr[kin["step"]], c)
    power = np.broadcast_to(cost.model.power_W(state), kin["t"].shape)
    return float(np.cumsum(power)[-1] * SAMPLE_DT_S), \
        cost.model.power_jacobian(state).sum(axis=0) * SAMPLE_DT_S


def random_polyline(rng) -> np.ndarray:
    """2-6 vertices in the field, now and then a repeated vertex or a very short hop."""
    pts = [rng.uniform([2.0, 2.0], [WIDTH_M - 2, HEIGHT_M - 2])]
    for _ in range(rng.integers(1, 6)):
        r = rng.random()
        if r < 0.1:
            pts.append(pts[-1].copy())
        elif r < 0.2:
            pts.append(np.clip(pts[-1] + rng.normal(0.0, 0.05, 2), 1.0, HEIGHT_M - 1))
        else:
            pts.append(rng.uniform([2.0, 2.0], [WIDTH_M - 2, HEIGHT_M - 2]))
    pts = np.array(pts)
    if np.hypot(*np.diff(pts, axis=0).T).sum() < 0.5:
        pts = np.array([pts[0], pts[0] + [1.0, 0.5]])
    return pts


def drawn_model(model, rng):
    """The model with every coefficient scaled by a random factor in [0.5, 1.5]."""
    return model.with_theta(dict(zip(model.names, model.theta * rng.uniform(0.5, 1.5,
                                                                            model.theta.size))))


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31), n_paths=st.integers(1, 12),
       speed=st.floats(0.2, 1.5), accel=st.floats(0.2, 2.0),
       duty=st.one_of(st.just(1.0), st.floats(0.4, 1.0)))
def test_kept_returns_give_the_energies_of_the_interpreted_drive(ctx, seed, n_paths, speed,
                                                                 accel, duty):
    """First call (driven), second call with another model and a shuffled, partly new set of
    paths (mostly reused): every energy and gradient within 1e-9 of the reference."""
    rng = np.random.default_rng(seed)
    exact = cost_contexts(ctx, build_rasters(ctx.world), speed)[1]
    cost = replace(exact, accel_max_mps2=accel,
                   conditions=Conditions(duty, 4.0, ctx.conditions.wind_xy_mps))
    paths = [random_polyline(rng) for _ in range(n_paths)]
    store = DrivenReturns()
    second = [paths[i] for i in rng.permutation(n_paths)] + [random_polyline(rng), paths[0]]
    for batch in (paths, second):
        steps, kins = store.driven(cost, batch)
        energy, gradient = driven_energies_and_gradients(cost.model, steps, kins,
                                                         cost.conditions)
        for xy, e, g in zip(batch, energy, gradient):
            want_e, want_g = reference_return(cost, xy)
            assert e == pytest.approx(want_e, rel=1e-9)
            np.testing.assert_allclose(g, want_g, rtol=1e-9, atol=1e-12 * np.abs(want_g).max())
        cost = replace(cost, model=drawn_model(cost.model, rng))
    assert store.misses == n_paths + 1 and store.hits == n_paths + 1


def test_another_setting_or_world_is_driven_again(ctx):
    """Cruise speed, acceleration limit, duty cycle and world (by identity) key the store;
    the model, wind and sensor rate enter only the power, evaluated afresh."""
    exact = cost_contexts(ctx, build_rasters(ctx.world))[1]
    path = [np.array([[10.0, 10.0], [60.0, 30.0], [70.0, 70.0]])]
    store = DrivenReturns()
    store.driven(exact, path)
    for same in (replace(exact, model=drawn_model(exact.model, np.random.default_rng(1))),
                 replace(exact, conditions=Conditions(exact.conditions.duty_cycle, 7.0,
                                                      (1.0, -2.0)))):
        (steps,), (kin,) = store.driven(same, path)
        energy, _ = driven_energies_and_gradients(same.model, [steps], [kin], same.conditions)
        assert energy[0] == pytest.approx(reference_return(same, path[0])[0], rel=1e-9)
    assert (store.misses, store.hits) == (1, 2)
    for changed in (replace(exact, speed_mps=exact.speed_mps * 0.9),
                    replace(exact, accel_max_mps2=exact.accel_max_mps2 * 2),
                    replace(exact, conditions=Conditions(0.6)),
                    replace(exact, world=replace(exact.world))):
        store.driven(exact, path)
        misses = store.misses
        (steps,), (kin,) = store.driven(changed, path)
        assert store.misses == misses + 1 and len(store) == 1
        energy, _ = driven_energies_and_gradients(changed.model, [steps], [kin],
                                                  changed.conditions)
        assert energy[0] == pytest.approx(reference_return(changed, path[0])[0], rel=1e-9)


def test_least_recently_used_paths_are_dropped_first(ctx):
    exact = cost_contexts(ctx, build_rasters(ctx.world))[1]
    paths = [np.array([[5.0 + i, 5.0], [5.0 + i, 40.0]]) for i in range(5)]
    store = DrivenReturns(max_paths=3)
    store.driven(exact, paths[:3])
    store.driven(exact, paths[:1])  # path 0 used again: path 1 is now the oldest
    store.driven(exact, paths[3:4])
    assert len(store) == 3
    store.driven(exact, [paths[0], paths[2], paths[3]])
    assert store.misses == 4  # all three still kept
    store.driven(exact, paths[1:2])
    assert store.misses == 5
    with pytest.raises(ValueError, match="max_paths"):
        DrivenReturns(max_paths=0)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), repeat=st.booleans(),
       chunks=st.lists(st.integers(1, 3000), min_size=1, max_size=4))
def test_compiled_driver_samples_are_the_interpreted_ones_bit_for_bit(seed, repeat, chunks):
    """Random sub-steps (zero-length ones included), speeds, grades, limits and stop
    intervals, single runs and laps, read in random chunks: the same samples and state."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 60))
    lengths = rng.exponential(2.0, n) * (rng.random(n) > 0.1)
    lengths[0] += 0.01  # a path of positive length
    args = (np.r_[0.0, np.cumsum(lengths)], rng.uniform(0.1, 2.0, n), rng.uniform(0.8, 1.0, n),
            rng.uniform(0.2, 2.0), rng.choice([0.05, 0.1, 0.25]),
            rng.choice([1.0, rng.uniform(0.4, 1.0)]), rng.uniform(0.3, 60.0), repeat)
    compiled, interpreted = Driver(*args), ReferenceDriver(*args)
    for size in chunks:
        got, want = compiled.run(size), interpreted.run(size)
        for key in want:
            assert got[key].dtype == want[key].dtype, key
            np.testing.assert_array_equal(got[key], want[key], err_msg=key)
        assert (compiled.s, compiled.v, compiled.t, compiled.moving, compiled.finished) == (
            interpreted.s, interpreted.v, interpreted.t, interpreted.moving,
            interpreted.finished)


def test_drive_compiles_in_memory_when_no_cache_location_is_writable(monkeypatch):
    """numba refuses ``cache=True`` (RuntimeError) when it can write its cache nowhere: the
    drive is then compiled for this process only, with the same samples."""
    import numba

    from orange_plan.physics import profile

    real_njit = numba.njit

    def refusing_cache(*args, **kwargs):
        if kwargs.get("cache"):
            raise RuntimeError("cannot cache function: no locator available")
        return real_njit(*args, **kwargs)

    monkeypatch.setattr(numba, "njit", refusing_cache)
    profile._compiled_drive_steps.cache_clear()
    try:
        args = (np.linspace(0.0, 30.0, 31), np.full(30, 1.2), np.ones(30), 0.5, 0.1, 0.8, 10.0)
        got, want = Driver(*args).run(10_000), ReferenceDriver(*args).run(10_000)
        for key in want:
            np.testing.assert_array_equal(got[key], want[key], err_msg=key)
    finally:
        profile._compiled_drive_steps.cache_clear()
