"""Reserve rules (planning/reserve.py): hand-computed sizes, broadcasting, bad input, and the
confidence rule's properties (never negative from p >= 0.5, monotone in p and in the variance,
its own slack giving back p)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from orange_plan.errors import InputError
from orange_plan.planning.reserve import (
    ConfidenceReserve,
    EnergyReserve,
    FractionReserve,
    ReserveRule,
    from_scenario,
    reserve_from,
)
from orange_plan.scenario import Reserve

Z_95 = 1.6448536269514722
"""Standard normal quantile at 0.95 (tables: 1.64485)."""

probabilities = st.floats(0.5, 0.999999)
variances = st.floats(0.0, 1e12)


# --- hand-computed values ------------------------------------------------------------------


def test_confidence_keeps_z_p_standard_deviations():
    # p = 0.95, sd 100 J: 1.64485 x 100 = 164.485 J; the energy and E_avail do not matter
    assert float(ConfidenceReserve(0.95).size_J(3000.0, 100.0**2, 5e4)) == pytest.approx(
        164.485, abs=1e-3)
    assert float(ConfidenceReserve(0.5).size_J(3000.0, 100.0**2, 5e4)) == pytest.approx(0.0,
                                                                                       abs=1e-12)
    assert float(ConfidenceReserve(0.99).size_J(0.0, 0.0, 5e4)) == 0.0


def test_fraction_keeps_a_share_of_the_available_energy():
    assert float(FractionReserve(0.1).size_J(3000.0, 1e6, 5e4)) == pytest.approx(5000.0)
    assert float(FractionReserve(0.0).size_J(3000.0, 1e6, 5e4)) == 0.0


def test_energy_keeps_its_joules():
    assert float(EnergyReserve(5000.0).size_J(3000.0, 1e6, 5e4)) == 5000.0


def test_return_only_is_the_return_s_spread_or_the_fixed_amount():
    # the way home alone: 1000 J with sd 50 J -> 1.64485 x 50 = 82.243 J at p = 0.95
    assert float(ConfidenceReserve(0.95).return_only_J(1000.0, 50.0**2, 5e4)) == pytest.approx(
        82.2427, abs=1e-3)
    assert float(FractionReserve(0.1).return_only_J(1000.0, 50.0**2, 5e4)) == pytest.approx(5e3)
    assert float(EnergyReserve(42.0).return_only_J(1000.0, 50.0**2, 5e4)) == 42.0


def test_return_probability_of_a_slack_and_a_spread():
    rule = ConfidenceReserve(0.95)
    assert float(rule.return_probability(164.485, 100.0)) == pytest.approx(0.95, abs=1e-6)
    assert float(rule.return_probability(0.0, 100.0)) == 0.5
    assert float(rule.return_probability(-100.0, 100.0)) == pytest.approx(0.158655, abs=1e-6)
    # no spread: certain either way; the same law whatever the rule
    assert float(rule.return_probability(0.0, 0.0)) == 1.0
    assert float(EnergyReserve(5.0).return_probability(-1e-9, 0.0)) == 0.0
    assert float(FractionReserve(0.1).return_probability(164.485, 100.0)) == pytest.approx(0.95,
                                                                                         abs=1e-6)


def test_budget_guesses():
    # 10 kJ left of 50 kJ: a tenth of E_avail is 5 kJ; a confidence of 0.95 with a 25 %
    # run-to-run spread keeps E z d: E (1 + 1.64485 x 0.25) = 1.41121 E = 10 kJ -> E = 7086.10 J
    assert FractionReserve(0.1).budget_guess_J(1e4, 5e4, 0.25) == pytest.approx(5e3)
    assert EnergyReserve(2e3).budget_guess_J(1e4, 5e4, 0.25) == pytest.approx(8e3)
    assert ConfidenceReserve(0.95).budget_guess_J(1e4, 5e4, 0.25) == pytest.approx(7086.10,
                                                                                   abs=0.01)
    assert ConfidenceReserve(0.95).budget_guess_J(1e4, 5e4, 0.0) == 1e4


def test_descriptions_and_rule_text():
    assert ConfidenceReserve(0.95).describe() == "95 % confidence of getting home"
    assert FractionReserve(0.1).describe() == "10 % of the available energy"
    assert EnergyReserve(5000).describe() == "5000 J"
    # the plan summary's reserve_rule keeps the scenario's spelling
    assert ConfidenceReserve(0.95).rule_text() == "confidence = 0.95"
    assert FractionReserve(0.1).rule_text() == "fraction = 0.1"
    assert EnergyReserve(5000).rule_text() == "energy_J = 5000"


def test_only_confidence_needs_variance_promises_a_probability_and_scales():
    assert ConfidenceReserve(0.9).needs_variance
    assert not FractionReserve(0.1).needs_variance and not EnergyReserve(1.0).needs_variance
    assert ConfidenceReserve(0.9).falls_short(0.89) and not ConfidenceReserve(0.9).falls_short(0.9)
    assert not FractionReserve(0.1).falls_short(0.0) and not EnergyReserve(1.0).falls_short(0.0)
    assert ConfidenceReserve(0.9).rescaled_J(100.0, 1.5) == 150.0
    assert FractionReserve(0.1).rescaled_J(100.0, 1.5) == 100.0
    assert EnergyReserve(1.0).rescaled_J(100.0, 1.5) == 100.0


def test_built_from_the_scenario_s_rule():
    assert from_scenario(Reserve("confidence", 0.95)) == ConfidenceReserve(0.95)
    assert from_scenario(Reserve("fraction", 0.1)) == FractionReserve(0.1)
    assert from_scenario(Reserve("energy_J", 42.0)) == EnergyReserve(42.0)
    rule = EnergyReserve(42.0)
    assert from_scenario(rule) is rule

    class Scenario:
        class mission:
            reserve = Reserve("fraction", 0.2)

    assert reserve_from(Scenario) == FractionReserve(0.2)
    assert isinstance(reserve_from(Scenario), ReserveRule)


# --- shapes --------------------------------------------------------------------------------


@pytest.mark.parametrize("rule", [ConfidenceReserve(0.9), FractionReserve(0.1),
                                  EnergyReserve(7.0)])
def test_sizes_broadcast_over_every_argument(rule):
    energy, var, avail = np.ones((3, 1)), np.full((1, 4), 25.0), np.full((3, 4), 1e3)
    assert rule.size_J(energy, var, 1e3).shape == (3, 4)
    assert rule.size_J(1.0, var, avail).shape == (3, 4)
    assert rule.size_J(energy, 25.0, 1e3).shape == (3, 1)
    assert rule.size_J(1.0, 25.0, 1e3).shape == ()
    assert rule.return_only_J(energy, var, 1e3).shape == (3, 4)
    # every element as the scalar call gives it
    np.testing.assert_allclose(rule.size_J(energy, var, avail), float(rule.size_J(1.0, 25.0, 1e3)))
    out = rule.size_J(1.0, var, 1e3)
    out[...] = -1.0  # a fresh array: writing to it changes nothing the rule holds
    assert float(rule.size_J(1.0, 25.0, 1e3)) != -1.0


def test_return_probability_broadcasts():
    p = ConfidenceReserve(0.9).return_probability(np.array([[0.0], [100.0]]),
                                                  np.array([0.0, 50.0, 100.0]))
    assert p.shape == (2, 3)
    np.testing.assert_allclose(p[0], [1.0, 0.5, 0.5])


def test_unreachable_points_stay_unknown():
    # an infinite energy has a nan variance (query_points): the reserve is nan, not an error
    assert np.isnan(ConfidenceReserve(0.9).size_J(np.inf, np.nan, 1e3))


# --- bad input -----------------------------------------------------------------------------


@pytest.mark.parametrize("make, value", [
    (ConfidenceReserve, 0.0), (ConfidenceReserve, 1.0), (ConfidenceReserve, -0.5),
    (ConfidenceReserve, 1.5), (ConfidenceReserve, float("nan")),
    (FractionReserve, -0.1), (FractionReserve, 1.0), (FractionReserve, float("nan")),
    (EnergyReserve, -1.0), (EnergyReserve, float("inf")), (EnergyReserve, float("nan")),
    (EnergyReserve, "lots"), (FractionReserve, None),
])
def test_bad_rules_are_input_errors(make, value):
    with pytest.raises(InputError, match="reserve"):
        make(value)


def test_unknown_scenario_rule_is_an_input_error():
    with pytest.raises(InputError, match="unknown reserve rule 'percent'"):
        from_scenario(Reserve("percent", 0.1))


# --- properties ----------------------------------------------------------------------------


@given(probabilities, variances, st.floats(0.0, 0.999), st.floats(0.0, 1e9),
       st.floats(0.0, 1e9))
def test_reserves_are_never_negative(p, var, f, e, avail):
    for rule in (ConfidenceReserve(p), FractionReserve(f), EnergyReserve(e)):
        assert float(rule.size_J(1e3, var, avail)) >= 0.0


@given(probabilities, probabilities, variances)
def test_confidence_reserve_grows_with_p(p1, p2, var):
    lo, hi = sorted((p1, p2))
    assert float(ConfidenceReserve(lo).size_J(0.0, var, 0.0)) <= float(
        ConfidenceReserve(hi).size_J(0.0, var, 0.0))


@given(st.floats(0.01, 0.99), variances, variances)
def test_confidence_reserve_grows_with_the_variance_above_one_half(p, v1, v2):
    lo, hi = sorted((v1, v2))
    rule = ConfidenceReserve(p)
    small, large = float(rule.size_J(0.0, lo, 0.0)), float(rule.size_J(0.0, hi, 0.0))
    # z_p < 0 below one half: a larger spread then counts on drawing still less
    assert small <= large if p >= 0.5 else small >= large


@given(st.floats(0.001, 0.999), st.floats(1e-3, 1e6))
def test_the_confidence_reserve_as_slack_gives_back_p(p, sd):
    rule = ConfidenceReserve(p)
    slack = rule.size_J(0.0, sd**2, 0.0)
    assert float(rule.return_probability(slack, sd)) == pytest.approx(p, rel=1e-9, abs=1e-12)
    # a slack short of the reserve by a tenth of a standard deviation falls short of p
    assert rule.falls_short(float(rule.return_probability(slack - 0.1 * sd, sd)))


# --- one place ------------------------------------------------------------------------------


def test_the_rule_is_read_and_the_normal_law_computed_in_one_module():
    import re

    from conftest import REPO

    own = {REPO / "orange_plan" / "planning" / "reserve.py", REPO / "orange_plan" / "scenario.py"}
    pattern = re.compile(r"reserve\.kind|NormalDist|stats import norm|norm\.(cdf|ppf)|ndtri?\b")
    found = [f"{path.relative_to(REPO)}:{n}" for path in (REPO / "orange_plan").rglob("*.py")
             if path not in own
             for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
             if pattern.search(line)]
    assert not found, f"reserve rules or the normal law outside planning/reserve.py: {found}"


def test_the_normal_upper_tail_by_hand_and_far_out():
    """``normal_upper_tail``: 1 - Phi(1.645) = 0.04998 and 1 - Phi(0) = 0.5 by the tables;
    at 8 it is 6.2e-16, where 1 - Phi(8) computed as a difference rounds to 0; arrays keep
    their shape."""
    import numpy as np

    from orange_plan.planning.reserve import normal_upper_tail

    assert normal_upper_tail(1.645) == pytest.approx(0.04998, abs=1e-5)
    assert normal_upper_tail(0.0) == 0.5
    assert normal_upper_tail(8.0) == pytest.approx(6.22e-16, rel=0.01)
    assert normal_upper_tail(np.zeros((2, 3))).shape == (2, 3)
