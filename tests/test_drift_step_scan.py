"""A step drift's time scan (``identify.diagnosis.effects._step_falls``): by cumulative sums,
the same fall of the residual sum of squares as projecting every step column on the
baseline's columns, on jittered sample times, held-out rows and a varying scale."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from orange_plan.identify.diagnosis.effects import _column_basis, _step_falls
from orange_plan.physics.terms import step_ramp


def _projected_falls(elapsed, rows, scale, resid, q, times):
    """The falls the slow way: every step column built, projected off the basis."""
    steps = step_ramp(elapsed[rows, None], times[None, :]) * scale[rows, None]
    own = steps - q @ (q.T @ steps)
    cc = np.einsum("ij,ij->j", own, own)
    spanned = cc <= 1e-9 * np.einsum("ij,ij->j", steps, steps)
    return np.where(spanned, -np.inf, (resid[rows] @ own) ** 2 / np.where(spanned, 1.0, cc))


def _case(seed: int, rate_hz: float, n: int = 600):
    rng = np.random.default_rng(seed)
    elapsed = np.cumsum(rng.uniform(0.5, 1.5, n) / rate_hz)
    elapsed -= elapsed[0]
    rows = rng.random(n) > 0.2
    rows[(n // 3):(n // 3 + n // 10)] = False  # a held-out stretch, as the folds leave
    scale = rng.uniform(0.0, 2.0, n)
    columns = np.column_stack([np.ones(n), elapsed, rng.normal(size=n)])
    q = _column_basis(columns[rows])
    resid = rng.normal(size=n) + 0.8 * (elapsed > elapsed[n // 2])
    times = np.arange(-2.0, elapsed[-1] + 3.0, 0.37)
    return elapsed, rows, scale, resid, q, times


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), rate_hz=st.sampled_from([0.5, 1.0, 2.0, 10.0]))
def test_cumulative_sums_give_the_projected_falls(seed, rate_hz):
    args = _case(seed, rate_hz)
    fast, slow = _step_falls(*args), _projected_falls(*args)
    assert np.array_equal(np.isfinite(fast), np.isfinite(slow))
    ok = np.isfinite(slow)
    assert np.allclose(fast[ok], slow[ok], rtol=1e-9, atol=1e-9 * np.max(np.abs(slow[ok])))


def test_a_step_the_constant_spans_has_no_fall_and_the_true_time_falls_most():
    elapsed, rows, scale, _resid, q, _times = _case(3, 1.0)
    ones = np.ones_like(scale)
    resid = 2.0 * (elapsed >= 300.0) + 0.01 * np.random.default_rng(0).normal(size=elapsed.size)
    times = np.array([-5.0, 150.0, 299.5, 450.0])
    fall = _step_falls(elapsed, rows, ones, resid, q, times)
    assert fall[0] == -np.inf  # from before the first sample: the constant column itself
    assert int(np.argmax(fall)) == 2 and np.all(fall >= 0.0, where=np.isfinite(fall))


@pytest.mark.parametrize("times", [np.array([]), np.array([1e9])])
def test_no_time_or_a_time_past_the_end_is_handled(times):
    elapsed, rows, scale, resid, q, _ = _case(1, 2.0)
    fall = _step_falls(elapsed, rows, scale, resid, q, times)
    assert fall.shape == times.shape
    assert np.all(fall == -np.inf)  # past the end the step is zero everywhere: nothing of its own
