"""The detection limit a diagnosis states for each candidate (``detection_limit_W``): the
smallest RMS power of that candidate which the recording would show with 95 % probability in
that round, i.e. pass its t bar with ``detection_power_z`` standard errors to spare.

Why it is stated this way: the limit is computed from one fit's standard errors; the
independent reference is the same recording with the candidate's own effect added at ``k``
times the stated limit, diagnosed again by refitting (``fit_design``) and judging
(``judge``). Each limit's worth of added effect must add one bar and the margin
(``MIN_T + Z``): at twice the limit it passes, at a third of it (where the noise gave the
candidate little t) it does not. A limit that was too low would let a user read "no
missing physics found" as ruling out effects the recording could in fact have hidden.
"""

from __future__ import annotations

import dataclasses
from functools import cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from orange_plan.identify.diagnose import (
    DEFAULT_SETTINGS,
    candidates,
    detection_limit_W,
    diagnose,
    fit_design,
    judge,
)
from orange_plan.identify.diagnosis.design import Effect
from orange_plan.identify.diagnosis.selection import _unexplained_spread
from orange_plan.sim.concealed import concealed_case

MIN_T = DEFAULT_SETTINGS.min_t
MIN_EFFECT_SHARE = DEFAULT_SETTINGS.min_effect_share
Z = DEFAULT_SETTINGS.detection_power_z

LINEAR = ("battery_temperature", "turning", "inertia")
"""Candidates of one coefficient whose column does not depend on the residual (a payload's
change time, a drift's shape and a wind are estimated from it, so an added step, trend or
wind moves them too)."""


@cache
def _null():
    case = concealed_case([], 0, kind="ground")
    return diagnose(case.recording, case.ctx)


def _candidate(name: str):
    return next(c for c in candidates() if c.id == name)


def _judged(d, cand):
    base, fit = fit_design(d, []), fit_design(d, [cand])
    return fit, judge(d, [cand], fit, base)


def _with_power(d, power_W):
    """The design of the same recording with ``power_W`` [W] more recorded power."""
    samples = dataclasses.replace(d.samples, power_W=d.samples.power_W + power_W)
    return dataclasses.replace(d, samples=samples, cache={})


def _unit(fit, i):
    """Coefficient ``i``'s column scaled to 1 W RMS."""
    return fit.x[:, i] / np.sqrt(np.mean(fit.x[:, i] ** 2))


@settings(max_examples=8, deadline=None, database=None, derandomize=True)
@given(name=st.sampled_from(LINEAR), k=st.floats(1.0, 3.0))
def test_each_limits_worth_of_effect_adds_one_t_bar(name, k):
    """``t(k + 1) - t(k) = MIN_T + Z``: the difference cancels the noise's own share of the
    t, which a coefficient held at its physical bound (0) would otherwise hide."""
    d = _null().design
    cand = _candidate(name)
    fit, trial = _judged(d, cand)
    unit = _unit(fit, fit.owned(name)[0])
    t = [_judged(_with_power(d, j * trial.detectable_W * unit), cand)[1].t_max
         for j in (k, k + 1.0)]
    assert t[0] > 0.0  # off its bound, where t is linear in the effect
    if trial.detectable_W <= MIN_EFFECT_SHARE * d.mean_power_W * (1 + 1e-9):
        # the power share, not the t bar, set this limit: a limit's worth is more than a bar
        assert t[1] - t[0] >= (MIN_T + Z) * 0.98, t
    else:
        # exact when the null's own fit is off its bound (turning); held at 0, its residual
        # differs from the injected fits' and so does its autocorrelation time
        assert t[1] - t[0] == pytest.approx(MIN_T + Z, rel=0.02), t


def test_twice_the_limit_passes_the_t_bar_a_third_does_not():
    d = _null().design
    cand = _candidate("turning")
    fit, trial = _judged(d, cand)
    unit = _unit(fit, fit.owned("turning")[0])
    t = {k: _judged(_with_power(d, k * trial.detectable_W * unit), cand)[1].t_max
         for k in (2.0, 1.0 / 3.0)}
    assert t[2.0] >= MIN_T > t[1.0 / 3.0], t


def test_the_limits_are_in_the_json_and_the_null_evidence():
    result = _null()
    assert result.verdict == "no missing physics found"
    singles = [c for c in result.to_dict()["candidates"] if "+" not in c["id"]]
    assert singles and all(c["detectable_W"] > 0 for c in singles)
    assert "detection limit" in result.evidence


def test_a_candidate_the_fit_cannot_move_has_no_limit():
    """No free coefficient (every standard error 0): no effect of it is detectable, the
    limit is infinite (null in the JSON)."""
    d = _null().design
    cand = _candidate("drift")
    fit = fit_design(d, [cand])
    pinned = dataclasses.replace(fit, sd=np.zeros_like(fit.sd))
    assert detection_limit_W(d, cand, pinned, fit, 100.0) == np.inf


def test_the_winds_limit_by_hand():
    """The wind is judged by the likelihood ratio: residual 2 W RMS, 100 effective samples,
    bar 4 and 1.645 to spare: an unexplained effect of RMS a is seen with 95 % probability
    from ``100 ln(4 / (4 - a^2)) = 5.645^2`` on, a = 2 sqrt(1 - exp(-0.31866)) = 1.04475 W;
    the power share floor (1 % of 10 W) is below."""
    from types import SimpleNamespace

    wind = _candidate("wind")
    d = SimpleNamespace(mean_power_W=10.0, settings=DEFAULT_SETTINGS)
    current = SimpleNamespace(rmse_W=2.0)
    assert detection_limit_W(d, wind, None, current, 100.0) == pytest.approx(1.0447535, rel=1e-6)
    # a large share floor wins
    big = SimpleNamespace(mean_power_W=1e3, settings=DEFAULT_SETTINGS)
    assert detection_limit_W(big, wind, None, current, 100.0) == pytest.approx(10.0)


SCANNED = ("drift", "drift_rolling", "payload")
"""Candidates of one coefficient whose shape or change time a scan chooses: they state a
limit at every alternative of the scan (``limits_by_alternative``)."""


def _forced(cand, column: np.ndarray):
    """``cand`` with its scan's choice fixed to ``column`` (the same id, so the same t bar
    with the scan's price)."""
    effect = Effect(column[:, None], ("fixed",), np.array([-np.inf]), np.array([np.inf]),
                    scanned=1)
    return dataclasses.replace(cand, effect=lambda _d, _resid, _rows: effect)


@pytest.mark.parametrize("name", SCANNED)
def test_each_alternatives_limit_is_the_limit_of_a_fit_that_tried_it(name):
    """The independent reference: the candidate refitted with its scan's choice fixed at the
    alternative (a fresh cache: the effect is cached by id), judged, its own
    ``detection_limit_W``. Equal up to the two fits' residuals (their variance and
    autocorrelation time differ by a few per cent on the null case: 0.4-6 % measured), and
    exactly equal at the shape the scan tried."""
    d = _null().design
    cand = _candidate(name)
    fit, trial = _judged(d, cand)
    alternatives = trial.detectable_W_by_alternative
    assert len(alternatives) == len(fit.alternatives[name].params) > 30
    columns = fit.alternatives[name].columns()
    for k in (0, 1, 3, 5, 6, len(alternatives) // 2, len(alternatives) - 1):
        fresh = dataclasses.replace(d, cache={})
        forced = _forced(cand, columns[:, k])
        reference = judge(fresh, [forced], fit_design(fresh, [forced]), fit_design(fresh, []))
        assert alternatives[k]["detectable_W"] == pytest.approx(reference.detectable_W,
                                                                rel=0.08), alternatives[k]
    tried = fit.params_of(name)[0]
    same = [a for a in alternatives if all(tried.get(k) == pytest.approx(v, abs=1e-6)
                                           for k, v in a.items() if k != "detectable_W")]
    for alternative in same:  # a line or a decay tried is on the grid; a refined step not
        assert alternative["detectable_W"] == pytest.approx(trial.detectable_W, rel=1e-9)


def test_a_slow_decay_has_a_higher_limit_than_a_fast_one():
    """The constant loads take up more of a slower decay (4800 s over a 30-minute run is
    nearly a line plus a constant), so less of it is its own: its limit is higher; a step
    near the start is nearly a constant too."""
    d = _null().design
    _fit, trial = _judged(d, _candidate("drift"))
    decays = {round(a["drift_tau_s"]): a["detectable_W"]
              for a in trial.detectable_W_by_alternative if "drift_tau_s" in a}
    taus = [decays[t] for t in (600, 1200, 2400, 4800)]
    assert taus == sorted(taus)
    steps = [a for a in trial.detectable_W_by_alternative if "drift_from_s" in a]
    assert steps[0]["detectable_W"] > 2 * steps[len(steps) // 2]["detectable_W"]


def test_other_candidates_and_pairs_state_no_alternatives():
    result = _null()
    for trial in result.trials:
        if "+" in trial.id or trial.id not in SCANNED:
            assert trial.detectable_W_by_alternative == (), trial.id
    rows = [c for c in result.to_dict()["candidates"] if c["id"] in SCANNED]
    assert rows and all(len(c["detectable_W_by_alternative"]) > 30 for c in rows)
    assert "by the shape or time its scan could choose" in result.evidence


def test_unexplained_spread_by_hand():
    """``c'c - c'x (x'x + w)^-1 x'c`` with x a column of ones and c = (1, 2, 3): 14 - 36 / 3
    = 2 without the ridge (the centred sum of squares), 14 - 36 / 4 = 5 with w = 1; a
    column the others span has only what the ridge keeps from it (12 - 36 / 4 = 3)."""
    x = np.ones((3, 1))
    c = np.array([[1.0, 2.0], [2.0, 2.0], [3.0, 2.0]])
    np.testing.assert_allclose(_unexplained_spread(x, np.zeros(1), c), [2.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(_unexplained_spread(x, np.ones(1), c), [5.0, 3.0],
                               atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(5, 60), p=st.integers(1, 4),
       ridge=st.floats(0.0, 10.0))
def test_property_unexplained_spread_is_the_ridge_least_squares_residual(seed, n, p, ridge):
    """Against ``lstsq`` on the stacked system: never negative, never more than ``c'c``."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, p)) * rng.uniform(0.01, 100.0, size=p)
    c = rng.normal(size=(n, 3))
    prior = np.full(p, ridge)
    got = _unexplained_spread(x, prior, c)
    stacked = np.vstack([x, np.diag(np.sqrt(prior))])
    padded = np.vstack([c, np.zeros((p, 3))])
    beta = np.linalg.lstsq(stacked, padded, rcond=None)[0]
    expected = np.sum((padded - stacked @ beta) ** 2, axis=0)
    assert np.all(got >= 0) and np.all(got <= np.sum(c**2, axis=0) * (1 + 1e-12))
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-9 * np.sum(c**2))
