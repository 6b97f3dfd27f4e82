"""How a round of diagnosis chooses among candidates that pass (``selection._round_choice``)
and how the information criterion charges a scanned parameter (``fitting.Fit.bic``)."""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from orange_plan.identify.diagnosis.fitting import Fit
from orange_plan.identify.diagnosis.selection import Scored, Trial, _round_choice
from orange_plan.identify.diagnosis.settings import DEFAULT_SETTINGS

N = 1000


def _fit(rmse_W: float, coefficients: int = 1, scanned: int = 0, tau: float = 10.0) -> Fit:
    zeros = np.zeros(N)
    return Fit(theta=np.zeros(coefficients), sd=np.ones(coefficients), predicted_W=zeros,
               held_out_W=zeros, cv_rmse_W=rmse_W, rmse_W=rmse_W, tau=tau, extra={},
               names=tuple(f"c{i}" for i in range(coefficients)),
               fold_ss=np.zeros(5), x=np.zeros((N, coefficients)), n_scanned=scanned,
               alternatives={}, ridge=np.zeros(coefficients))


def _scored(name: str, rmse_W: float, gain: float, accepted: bool, priced_out: bool = False,
            scanned: int = 0) -> Scored:
    trial = Trial(name, gain, 5.0, -10.0, accepted, "" if accepted else "t", 5, 1.0, 4.0,
                  priced_out)
    return Scored([SimpleNamespace(id=name)], _fit(rmse_W, scanned=scanned), trial)


DESIGN = SimpleNamespace(settings=DEFAULT_SETTINGS)
CURRENT = _fit(2.0, tau=10.0)


def test_a_scanned_parameter_costs_what_a_coefficient_costs():
    """BIC = n_eff ln(s^2) + k ln(n_eff), n_eff = n / tau, k counting the scanned
    parameters: 1000 samples at tau 10, one coefficient and one scanned time, RMSE 1.5 W."""
    fit = _fit(1.5, coefficients=1, scanned=1)
    by_hand = 100 * math.log(1.5**2) + 2 * math.log(100)
    assert fit.bic(10.0) == pytest.approx(by_hand)
    assert fit.bic(10.0) - replace(fit, n_scanned=0).bic(10.0) == pytest.approx(math.log(100))


def test_a_round_takes_the_lowest_criterion_not_the_largest_held_out_gain():
    """Two candidates that pass: a power step with the larger held-out gain, a payload that
    fits the recording better (its BIC 100 ln(1.1^2/1.2^2) = -17 lower): the payload."""
    step = _scored("drift", 1.2, 0.11, True, scanned=1)
    payload = _scored("payload", 1.1, 0.07, True, scanned=1)
    assert _round_choice(DESIGN, [step, payload], CURRENT) is payload


def test_a_candidate_refused_by_its_scan_price_may_stand_in_for_one_that_passes():
    """The drift fits better but misses its scan's price; the battery's loss passes: once the
    loss has shown that something is missing, the drift is the better explanation."""
    drift = _scored("drift", 1.50, 0.066, False, priced_out=True, scanned=1)
    loss = _scored("battery_temperature", 1.56, 0.054, True)
    assert _round_choice(DESIGN, [drift, loss], CURRENT) is drift


def test_the_scan_price_still_holds_where_nothing_else_passes():
    """No candidate passes: a scanned candidate refused only by its price is not named."""
    drift = _scored("drift", 1.5, 0.066, False, priced_out=True, scanned=1)
    weak = _scored("surface_rolling", 1.6, 0.04, False)
    assert _round_choice(DESIGN, [drift, weak], CURRENT) is None


def test_within_the_evidence_margin_the_held_out_gain_decides():
    """Two passing candidates whose BIC differ by less than ``min_bic_evidence``: the one
    that predicts the held-out blocks better."""
    rmse = 1.2
    # a BIC 1 apart at 100 effective samples: ln(s2^2 / s1^2) = 0.01
    close = rmse * math.exp(0.005)
    payload = _scored("payload", close, 0.066, True, scanned=1)
    rolling = _scored("drift_rolling", rmse, 0.060, True, scanned=1)
    gap = payload.fit.bic(10.0) - rolling.fit.bic(10.0)
    assert 0 < gap < DEFAULT_SETTINGS.min_bic_evidence
    assert _round_choice(DESIGN, [rolling, payload], CURRENT) is payload
    far = _scored("payload", rmse * math.exp(0.05), 0.066, True, scanned=1)
    assert _round_choice(DESIGN, [rolling, far], CURRENT) is rolling
