"""bench.identify: the reserve check of the calibration and online benchmarks, by hand."""

from __future__ import annotations

import pytest

from orange_plan.bench.identify import coverage_summary, reserve_exceeded


def test_reserve_exceeded_uses_the_planners_confidence_reserve():
    # z_0.9 = 1.2816, z_0.95 = 1.6449: with sd 10 J the reserves are 12.8 J and 16.4 J
    recorded, predicted, sd = [110.0, 115.0, 120.0], [100.0, 100.0, 100.0], [10.0, 10.0, 10.0]
    assert reserve_exceeded(recorded, predicted, sd, 0.9).tolist() == [False, True, True]
    assert reserve_exceeded(recorded, predicted, sd, 0.95).tolist() == [False, False, True]


def test_coverage_summary_counts_runs_per_confidence():
    out = coverage_summary([110.0, 115.0, 120.0, 50.0], [100.0] * 4, [10.0] * 4, "_prior")
    assert out == {"exceed_p90_prior_pct": pytest.approx(50.0), "exceed_p90_prior_runs": 2,
                   "exceed_p95_prior_pct": pytest.approx(25.0), "exceed_p95_prior_runs": 1}
