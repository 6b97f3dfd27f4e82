"""Property: whenever the session says "continue", the robot can get home with its reserve.

Random states along a plan (a point on a random tour segment, a random energy already used,
every reserve rule) are fed to a session as two still samples at that point whose power is
the model's own standing power, so the online model stays the scenario's. When the decision
is "continue", its homing margin is >= 0 and, as an independent reference, a fresh
``reach`` analysis from that position with that energy used (its own Dijkstra from the
position over its own roadmap, its own exact return and reserve) with the session's online
model says home is reachable. When the margin is negative the decision is "return_home".
"""

from __future__ import annotations

from dataclasses import replace

import pandas as pd
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from planning_worlds import write_world

from orange_plan.context import load_context
from orange_plan.physics.state import MotionState
from orange_plan.planning.reach import home_status, prepare_reach
from orange_plan.planning.session import MissionSession

N_VERTICES = 300
RESERVES = ({"fraction": 0.1}, {"confidence": 0.95}, {"energy_J": 200.0})


@pytest.fixture(scope="module")
def missions(tmp_path_factory):
    """One small world per reserve rule, with its first plan."""
    out = []
    for k, reserve in enumerate(RESERVES):
        folder = tmp_path_factory.mktemp(f"prop{k}")
        ctx = load_context(write_world(folder, width_m=36.0, height_m=24.0,
                                       obstacles=[(14, 4, 18, 16)], hill=(28, 12, 3, 5),
                                       rated_energy_Wh=0.5, reserve=reserve))
        session = MissionSession(ctx, n_vertices=N_VERTICES, seed=0,
                                 planner_kwargs={"max_candidates": 50})
        out.append((ctx, session.plan))
    return out


@pytest.mark.timeout(300)
@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(which=st.integers(0, len(RESERVES) - 1), where=st.floats(0, 1), along=st.floats(0, 1),
       used=st.floats(0, 1))
def test_continue_means_home_is_reachable(missions, which, where, along, used):
    ctx, plan = missions[which]
    i = min(int(where * (len(plan.xy_m) - 1)), len(plan.xy_m) - 2)
    xy = plan.xy_m[i] + along * (plan.xy_m[i + 1] - plan.xy_m[i])
    energy = used * ctx.scenario.battery.usable_J
    standing_W = float(ctx.model.power_W(MotionState(speed_mps=0.0,
                                                     sensor_rate_Hz=ctx.conditions.sensor_rate_Hz)))
    session = MissionSession(ctx, plan, n_vertices=N_VERTICES, seed=0)
    t1 = max(energy / standing_W, 1e-3)
    d = session.feed(pd.DataFrame({"t_s": [0.0, t1], "power_W": standing_W,
                                   "x_m": xy[0], "y_m": xy[1]}))
    assert d.energy_used_J == pytest.approx(standing_W * t1)
    assert d.homing_margin_J == pytest.approx(
        ctx.scenario.battery.usable_J - d.energy_used_J - d.energy_to_home_J - d.reserve_J)
    event(d.action)
    if d.homing_margin_J < 0:
        assert d.action == "return_home"
        return
    if d.action != "continue":
        return
    fresh = prepare_reach(replace(ctx, model=session.online_model), tuple(xy), d.energy_used_J,
                          n_vertices=N_VERTICES, seed=0)
    status = home_status(fresh)
    assert status.reachable, (xy, d, status)
    # the same return to within the roadmap joins (a fresh start vertex has its own edges,
    # the session joins the position to its nearest vertices): a sanity check of magnitude
    assert status.energy_to_home_J == pytest.approx(d.energy_to_home_J, rel=0.25, abs=10.0)
