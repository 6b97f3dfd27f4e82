"""physics.profile.drive_returns / profile_energies_and_gradients: many single runs at once give,
path by path, what drive_path / profile_energy / profile_gradient give."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from planning_worlds import write_world

from orange_plan.context import load_context
from orange_plan.physics.conditions import Conditions
from orange_plan.physics.pathcost import subdivide
from orange_plan.physics.profile import (
    drive_path,
    drive_returns,
    profile_energies_and_gradients,
    profile_energy,
    profile_gradient,
)

WIDTH_M, HEIGHT_M = 160.0, 120.0
KIN = ("v", "accel", "step")


@pytest.fixture(scope="module")
def worlds(tmp_path_factory):
    """A hilly field with a slow strip under two models: the reference terms (turning and a
    sensor rate), and inertia + regen with drag in a wind."""
    out = {}
    for name, extra in {"reference": {},
                        "inertia_regen_wind": {"model": {"terms": ["inertia", "regen"]},
                                               "environment": {"wind_speed_mps": 3.0,
                                                               "wind_from_deg": 60.0}}}.items():
        folder = tmp_path_factory.mktemp(name)
        path = write_world(folder, width_m=WIDTH_M, height_m=HEIGHT_M,
                           hill=(60.0, 50.0, 12.0, 18.0), ramp=0.03, turn=8.0, drag=0.6,
                           surfaces=[(100.0, 0.0, 120.0, HEIGHT_M, 0.15)], name=name)
        scenario = tomllib.loads(path.read_text(encoding="utf-8"))
        scenario["ancillary"]["sensor_rate_Hz"] = 5.0
        scenario["ancillary"]["s1_W_per_Hz"] = 0.2
        for section, values in extra.items():
            scenario.setdefault(section, {}).update(values)
        path.write_text(tomli_w.dumps(scenario), encoding="utf-8")
        out[name] = load_context(path)
    return out


def polyline(seed: int, length_m: float) -> np.ndarray:
    """A random polyline of horizontal length ``length_m`` inside the field: random vertices
    (now and then a repeated one or a very short hop), cut at the length, driven back and forth
    when they fall short."""
    rng = np.random.default_rng(seed)
    pts = [rng.uniform([2.0, 2.0], [WIDTH_M - 2, HEIGHT_M - 2])]
    for _ in range(rng.integers(1, 8)):
        r = rng.random()
        if r < 0.1:
            pts.append(pts[-1].copy())  # zero-length segment
        elif r < 0.2:
            pts.append(np.clip(pts[-1] + rng.normal(0.0, 0.05, 2), 1.0, WIDTH_M - 1))
        else:
            pts.append(rng.uniform([2.0, 2.0], [WIDTH_M - 2, HEIGHT_M - 2]))
    pts = np.array(pts)
    if np.hypot(*np.diff(pts, axis=0).T).sum() < 1e-3:
        pts = np.array([pts[0], np.clip(pts[0] + [1.0, 0.5], 1.0, HEIGHT_M - 1)])
    while np.hypot(*np.diff(pts, axis=0).T).sum() < length_m:
        pts = np.vstack([pts, pts[-2::-1]])
    seg = np.hypot(*np.diff(pts, axis=0).T)
    cum = np.r_[0.0, np.cumsum(seg)]
    i = int(np.searchsorted(cum, length_m, side="left"))  # cum[i - 1] < length_m <= cum[i]
    frac = (length_m - cum[i - 1]) / seg[i - 1]
    end = pts[i - 1] + frac * (pts[i] - pts[i - 1])
    return np.vstack([pts[:i], end])


def random_paths(world, seeds, lengths, speed_seeds):
    steps, speeds = [], []
    for seed, length, sseed in zip(seeds, lengths, speed_seeds):
        xy = polyline(seed, length)
        st_ = subdivide(world, xy[:-1], xy[1:])
        seg_speed = np.random.default_rng(sseed).uniform(0.2, 2.0, len(xy) - 1)
        steps.append(st_)
        speeds.append(st_.per_step(seg_speed))
    return steps, speeds


def returns_of(steps, speeds, accel, conditions, *rest):
    """``drive_returns`` called with ``drive_path``'s arguments."""
    return drive_returns(steps, speeds, accel, conditions.duty_cycle, *rest)


def assert_same_drive(batch, reference):
    """``drive_returns``' samples and yaw rates are ``drive_path``'s."""
    assert len(batch) == len(reference)
    for kin, (ref_kin, ref_state) in zip(batch, reference):
        for key in KIN:
            assert kin[key].shape == ref_kin[key].shape, key
            assert kin[key].dtype == ref_kin[key].dtype, key
            np.testing.assert_array_equal(kin[key], ref_kin[key], err_msg=key)
        np.testing.assert_array_equal(kin["yaw_radps"], ref_state.yaw_rate_radps)


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(variant=st.sampled_from(["reference", "inertia_regen_wind"]),
       n_paths=st.integers(1, 30), base_seed=st.integers(0, 2**31),
       lengths=st.lists(st.floats(0.5, 500.0), min_size=30, max_size=30),
       accel=st.floats(0.2, 2.0), duty=st.one_of(st.just(1.0), st.floats(0.5, 1.0)))
def test_batch_equals_one_drive_path_per_path(worlds, variant, n_paths, base_seed, lengths,
                                              accel, duty):
    ctx = worlds[variant]
    world, model = ctx.world, ctx.model
    seeds = [base_seed + 2 * i for i in range(n_paths)]
    steps, speeds = random_paths(world, seeds, lengths[:n_paths], [s + 1 for s in seeds])
    args = (accel, Conditions(duty, ctx.conditions.sensor_rate_Hz, ctx.conditions.wind_xy_mps))
    reference = [drive_path(s, v, *args) for s, v in zip(steps, speeds)]
    assert any(np.any(s.cos_t < 1.0) for s in steps)  # graded paths
    assert_same_drive(returns_of(steps, speeds, *args), reference)

    energy, gradient = profile_energies_and_gradients(model, steps, speeds, *args)
    assert energy.shape == (n_paths,) and gradient.shape == (n_paths, len(model.theta))
    ref_energy = [profile_energy(model, s, v, *args).total_J for s, v in zip(steps, speeds)]
    ref_gradient = np.array([profile_gradient(model, s, v, *args) for s, v in zip(steps, speeds)])
    np.testing.assert_allclose(energy, ref_energy, rtol=1e-9, atol=0)
    np.testing.assert_allclose(gradient, ref_gradient, rtol=1e-9,
                               atol=1e-12 * np.abs(ref_gradient).max())


@pytest.mark.parametrize("dt, every, duty", [(0.1, 5.0, 0.6), (0.05, 60.0, 0.9),
                                             (0.25, 20.0, 1.0), (0.1, 0.3, 0.5)])
def test_time_step_and_stop_interval_as_drive_path(worlds, dt, every, duty):
    """Other sample periods and frequent duty-cycle stops (a stop every few samples)."""
    ctx = worlds["reference"]
    steps, speeds = random_paths(ctx.world, [3, 5, 7, 9], [30.0, 2.0, 75.0, 0.5], [4, 6, 8, 10])
    args = (0.7, Conditions(duty, ctx.conditions.sensor_rate_Hz, ctx.conditions.wind_xy_mps), dt,
            every)
    reference = [drive_path(s, v, *args) for s, v in zip(steps, speeds)]
    assert_same_drive(returns_of(steps, speeds, *args), reference)
    energy, gradient = profile_energies_and_gradients(ctx.model, steps, speeds, *args)
    np.testing.assert_allclose(
        energy, [profile_energy(ctx.model, s, v, *args).total_J for s, v in zip(steps, speeds)],
        rtol=1e-9)
    np.testing.assert_allclose(
        gradient, [profile_gradient(ctx.model, s, v, *args) for s, v in zip(steps, speeds)],
        rtol=1e-9, atol=1e-9)


def test_short_and_zero_length_sub_steps(worlds):
    """Sub-steps shorter than a time step's travel (several edges passed in one step) and
    repeated vertices (zero-length sub-steps), next to ordinary paths."""
    world = worlds["reference"].world
    xy_a = np.array([[10.0, 10.0], [10.0, 10.0], [10.01, 10.0], [10.02, 10.0], [10.02, 10.0],
                     [30.0, 12.0], [30.05, 12.0], [30.0, 12.0]])
    xy_b = np.array([[50.0, 40.0], [80.0, 70.0]])
    xy_c = np.array([[70.0, 50.0], [70.0, 50.0001]])  # shorter than the arrival tolerance + 1e-6
    steps = [subdivide(world, xy[:-1], xy[1:]) for xy in (xy_a, xy_b, xy_c)]
    speeds = [np.full(s.horiz_m.size, 2.0) for s in steps]
    args = (2.0, Conditions(0.8, 5.0, worlds["reference"].conditions.wind_xy_mps))
    assert_same_drive(returns_of(steps, speeds, *args),
                      [drive_path(s, v, *args) for s, v in zip(steps, speeds)])


def test_no_paths(worlds):
    model = worlds["reference"].model
    assert returns_of([], [], 0.5, Conditions(0.9)) == []
    energy, gradient = profile_energies_and_gradients(model, [], [], 0.5, Conditions(0.9))
    assert energy.shape == (0,) and gradient.shape == (0, len(model.theta))


def test_lengths_must_agree(worlds):
    world = worlds["reference"].world
    steps = subdivide(world, [[1.0, 1.0]], [[5.0, 1.0]])
    with pytest.raises(ValueError, match="speed"):
        returns_of([steps, steps], [np.ones(steps.horiz_m.size)], 0.5, Conditions(0.9))
