"""mission: the time-limit rule every planner applies."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from orange_plan.mission import check_time_limit


def test_time_limit_rule_and_reason():
    assert check_time_limit(3599.0, 3600.0).within
    assert check_time_limit(3600.0, 3600.0).within  # the limit itself is allowed
    assert check_time_limit(1e9, None).within and check_time_limit(1e9, None).reason is None
    over = check_time_limit(18_383.2, 60.0)
    assert not over.within
    assert over.reason == "mission time 18,383 s exceeds mission.time_limit_s = 60 s"


@given(duration=st.floats(0.0, 1e7), limit=st.none() | st.floats(1e-3, 1e7))
def test_within_exactly_when_no_limit_or_not_longer(duration, limit):
    check = check_time_limit(duration, limit)
    assert check.within == (limit is None or duration <= limit)
    assert (check.reason is None) == check.within
