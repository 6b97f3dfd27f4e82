"""Heating or cooling that follows the ambient temperature on a trip (no HVAC meter), where the
ambient spans only a few kelvin (``sim.concealed`` case ``hvac_trip``): diagnosis names it when
its power is above the detection limit it states, and the constant loads do not swallow it."""

from __future__ import annotations

import numpy as np
import pytest

from orange_plan.bench.diagnose import oracle, with_stated_limits
from orange_plan.identify.diagnose import diagnose
from orange_plan.sim.concealed import TRIP_AMBIENT_SPAN_K, concealed_case


@pytest.mark.parametrize(("seed", "share_of_limit"), [(0, 1.0), (3, 0.85)])
def test_trip_hvac_is_found_with_its_coefficient(seed, share_of_limit):
    """Seed 0 cools over 22-31 C, at 2.1 times its stated limit; seed 3 heats over 5-10 C,
    at 0.91 times it (the limit is the size seen 19 times in 20; one a little under it is
    still seen more often than not, and this one is, at t 6.8 told the truth): both always on one side of the setpoint, so most of the power is a constant the
    refitted ancillary loads could take; its variation with the ambient names it."""
    case = concealed_case(["hvac_trip"], seed)
    span = np.ptp(case.frame["ambient_C"].to_numpy())
    assert TRIP_AMBIENT_SPAN_K[0] - 0.1 <= span <= TRIP_AMBIENT_SPAN_K[1] + 0.1
    result = diagnose(case.recording, case.ctx)
    told = with_stated_limits(oracle(result, case.truth), result, case.truth)
    assert told[0]["effect_W"] > share_of_limit * told[0]["stated_limit_W"]
    assert [(f.term, f.variant) for f in result.findings] == [("hvac", "hvac_ambient")]
    found = result.findings[0]
    for name, true in case.truth["hvac_trip"].items():
        assert abs(found.params[name] - true) <= 3 * found.stderr[name], (name, found.params,
                                                                         true)
