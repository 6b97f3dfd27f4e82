"""The battery's usable energy from its state of charge (identify.soc), and the session that
counts on it: an aged battery must not be spent as if it were new."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from orange_plan.context import load_context
from orange_plan.identify.soc import MIN_SPAN, SocCapacity
from orange_plan.planning.session import MissionSession
from orange_plan.sim.route import Route
from orange_plan.sim.simulator import simulate
from orange_plan.sim.truth import Truth


def test_hand_computed_line():
    # soc = 0.9 - E / 50 kJ: empty at E = 0.9 * 50 kJ = 45 kJ
    c = SocCapacity()
    e = np.arange(0.0, 20_001.0, 1000.0)
    c.add(e, 0.9 - e / 50_000.0)
    assert c.usable_J() == pytest.approx(45_000.0)
    assert c.span == pytest.approx(0.4)


def test_batches_add_up_to_the_whole():
    e = np.linspace(5_000.0, 30_000.0, 200)
    soc = 1.0 - e / 80_000.0
    whole, parts = SocCapacity(), SocCapacity()
    whole.add(e, soc)
    for lo in range(0, 200, 17):
        parts.add(e[lo:lo + 17], soc[lo:lo + 17])
    assert parts.usable_J() == pytest.approx(whole.usable_J(), rel=1e-9)
    assert whole.usable_J() == pytest.approx(80_000.0, rel=1e-9)


def test_silent_until_the_charge_has_fallen_enough():
    c = SocCapacity()
    e = np.linspace(0.0, 1000.0, 50)
    c.add(e, 1.0 - e / 1e6)  # a 0.1 % fall
    assert c.usable_J() is None
    c.add([2000.0], [np.nan])  # no reading
    c.add([3000.0], [1.7])  # not a state of charge
    assert c.n == 50 and c.usable_J() is None


def test_a_charge_that_does_not_fall_with_the_energy_says_nothing():
    c = SocCapacity()
    e = np.linspace(0.0, 10_000.0, 50)
    c.add(e, 0.5 + e / 100_000.0)  # rises: a gauge being charged or miswired
    assert c.usable_J() is None


def test_shapes_must_match():
    with pytest.raises(ValueError, match="energy_J has 3 values but soc 2"):
        SocCapacity().add([1.0, 2.0, 3.0], [0.5, 0.4])


@settings(max_examples=60, deadline=None)
@given(capacity_J=st.floats(1e3, 1e8), start=st.floats(0.0, 0.5), fall=st.floats(MIN_SPAN, 0.45),
       n=st.integers(10, 400), step=st.sampled_from([0.0, 0.001, 0.01]))
def test_a_gauge_in_steps_gives_the_capacity_within_its_resolution(capacity_J, start, fall, n,
                                                                    step):
    """Against the line the readings came from: exact readings give the capacity exactly; a
    gauge that rounds to ``step`` moves the answer by at most about step / fall of it (the
    line's slope is known to within the rounding over the fall)."""
    e = np.linspace(start * capacity_J, (start + fall) * capacity_J, n)
    soc = 1.0 - e / capacity_J
    if step:
        soc = np.round(soc / step) * step
    c = SocCapacity()
    c.add(e, soc)
    if c.span < MIN_SPAN:
        assert c.usable_J() is None
        return
    got = c.usable_J()
    assert got == pytest.approx(capacity_J, rel=1e-6 + 3.0 * step / c.span)


@pytest.fixture(scope="module")
def aged(tmp_path_factory):
    """A yard, its first tour, and the tour flown with a battery at 70 % of the scenario's."""
    from planning_worlds import write_world

    folder = tmp_path_factory.mktemp("soc")
    ctx = load_context(write_world(folder, width_m=60.0, height_m=40.0,
                                   obstacles=[(20, 8, 26, 30)], rated_energy_Wh=1.0))
    kw = dict(n_vertices=400, seed=0, planner_kwargs={"max_candidates": 80})
    plan = MissionSession(ctx, **kw).plan
    sim = simulate(ctx, Route(plan.xy_m, plan.speed_mps, "plan"),
                   Truth(capacity_factor=0.7), seed=1)
    return ctx, plan, kw, sim.frame


def _feed(ctx, plan, kw, frame, columns):
    session = MissionSession(ctx, plan, **kw)
    part = frame.iloc[: len(frame) // 2][list(columns)]
    for a in range(0, len(part), 20):
        d = session.feed(part.iloc[a:a + 20])
    return session, d


def test_session_counts_on_the_capacity_the_charge_shows(aged):
    ctx, plan, kw, frame = aged
    claimed = ctx.scenario.battery.usable_J
    cols = ["t_s", "power_W", "x_m", "y_m", "v_mps"]
    _, d_blind = _feed(ctx, plan, kw, frame, cols)
    seeing, d_seeing = _feed(ctx, plan, kw, frame, [*cols, "soc"])
    assert d_blind.energy_available_J == pytest.approx(claimed)
    assert d_seeing.energy_available_J == pytest.approx(0.7 * claimed, rel=0.03)
    assert seeing.capacity_shortfall_J == pytest.approx(0.3 * claimed, rel=0.1)
    # the margin is that of the smaller battery
    d = d_seeing
    assert d.homing_margin_J == pytest.approx(
        d.energy_available_J - d.energy_used_J - d.energy_to_home_J - d.reserve_J)
    assert d.homing_margin_J < d_blind.homing_margin_J - 0.2 * claimed


def test_a_gauge_reading_high_never_adds_energy(aged):
    ctx, plan, kw, frame = aged
    high = frame.assign(soc=1.0 - (1.0 - frame["soc"]) * 0.5)  # shows a battery twice as big
    session, d = _feed(ctx, plan, kw, high, ["t_s", "power_W", "x_m", "y_m", "soc"])
    assert session._soc.usable_J() > 1.2 * ctx.scenario.battery.usable_J
    assert d.energy_available_J == pytest.approx(ctx.scenario.battery.usable_J)


def test_the_low_estimate_takes_off_what_a_gauge_step_over_the_fall_leaves_unknown():
    """soc = 1 - E / 1000 J read from 0 to 100 J: C = 1000 J, 900 J left, a 10 % fall: a
    1 % step makes the slope uncertain by a tenth, so 90 J come off."""
    from orange_plan.identify.soc import SocCapacity

    gauge = SocCapacity()
    e = np.linspace(0.0, 100.0, 21)
    gauge.add(e, 1.0 - e / 1000.0)
    assert gauge.usable_J() == pytest.approx(1000.0)
    assert gauge.usable_low_J() == pytest.approx(910.0)
    gauge.add(np.linspace(100.0, 500.0, 41), 1.0 - np.linspace(100.0, 500.0, 41) / 1000.0)
    assert gauge.usable_low_J() == pytest.approx(1000.0 - 500.0 * 0.01 / 0.5)  # it shrinks


def test_no_low_estimate_before_the_charge_has_fallen():
    from orange_plan.identify.soc import SocCapacity

    gauge = SocCapacity()
    gauge.add(np.linspace(0.0, 10.0, 5), np.full(5, 1.0))
    assert gauge.usable_low_J() is None
