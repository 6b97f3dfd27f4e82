"""Telemetry a robot cannot have sent: positions off the map or inside an obstacle, negative
power beyond a full battery, negative time. One rule for every entry point: the Python API
(``MissionSession.feed``), the HTTP telemetry endpoint, and the commands that read
recordings (predict, calibrate, diagnose).

The map is the lab box (``scenarios/rusti_v1_box.toml``): 8 m x 6 m, a central block
x 2.5..5.5, y 2..4, a tool cabinet x 7.3..7.9, y 4.6..5.8, home (1, 1).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from conftest import REPO, run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from orange_plan.context import load_context
from orange_plan.errors import InputError
from orange_plan.planning.session import ACTIONS, FLAGS, MissionSession
from orange_plan.sim.route import Route
from orange_plan.sim.simulator import simulate
from orange_plan.telemetry.recording import write_recording

SCENARIO = REPO / "scenarios" / "rusti_v1_box.toml"
KW = dict(n_vertices=300, seed=0)
OFF_MAP = [(100.0, 100.0), (-50000.0, 3.0), (4.0, 1e7), (-30.0, -30.0), (19.0, 3.0)]
"""Positions more than 10 m beyond the 8 m x 6 m box: another frame, refused."""
IN_OBSTACLE = [(4.0, 3.0), (2.6, 2.1), (7.6, 5.2)]
"""Inside the central block or the tool cabinet."""
PAST_BOUNDARY = [(8.5, 3.0), (-2.0, 1.0), (4.0, 6.5)]
"""Just outside the boundary (GNSS noise at the edge): on the map, not in its free space."""
HOME = (1.0, 1.0)


@pytest.fixture(scope="module")
def mission():
    ctx = load_context(SCENARIO)
    return ctx, MissionSession(ctx, **KW).plan


def batch(t0: float, xy, n: int = 5, power_W: float = 9.0) -> list[dict]:
    """``n`` samples 1 s apart after ``t0``, the last at ``xy`` (the others near home)."""
    rows = [{"t_s": t0 + i, "power_W": power_W, "x_m": HOME[0] + 0.05 * i, "y_m": HOME[1]}
            for i in range(1, n)]
    return [*rows, {"t_s": t0 + n, "power_W": power_W, "x_m": xy[0], "y_m": xy[1]}]


def is_flag(d) -> bool:
    """A flagged decision: no energy figure that depends on the position, no "continue"."""
    return (d.action in FLAGS and "not where the map says" in d.reason
            and all(math.isnan(v) for v in (d.energy_to_home_J, d.homing_margin_J,
                                             d.return_probability, d.remaining_range_m)))


# --- A: positions, Python API -------------------------------------------------------------
@pytest.mark.parametrize("xy", OFF_MAP)
def test_off_map_position_is_refused_and_named(mission, xy):
    ctx, plan = mission
    session = MissionSession(ctx, plan, **KW)
    session.feed(batch(0.0, HOME))
    before = (session.energy_used_J, session.time_s, len(session.trail_xy_m))
    with pytest.raises(InputError, match=r"outside the map's boundary box") as err:
        session.feed(batch(10.0, xy))
    assert f"({xy[0]:g}, {xy[1]:g}) m" in str(err.value) and "\n" not in str(err.value)
    assert (session.energy_used_J, session.time_s, len(session.trail_xy_m)) == before


@pytest.mark.parametrize("xy, action", [*((p, "position_in_obstacle") for p in IN_OBSTACLE),
                                        *((p, "off_map_position") for p in PAST_BOUNDARY)])
def test_position_outside_free_space_is_flagged_then_clears(mission, xy, action):
    ctx, plan = mission
    session = MissionSession(ctx, plan, **KW)
    session.feed(batch(0.0, HOME))
    d = session.feed(batch(10.0, xy))
    assert d.action == action and is_flag(d), d
    assert d.energy_used_J > 0  # the energy is counted all the same
    back = session.feed(batch(20.0, (1.5, 1.0)))
    assert back.action in ("continue", "replan", "return_home")
    assert math.isfinite(back.energy_to_home_J)


@pytest.mark.parametrize("xy", [IN_OBSTACLE[0], (-9.0, -9.0), (17.0, 15.0)])
def test_a_position_glitch_counts_its_energy_but_teaches_nothing(mission, xy):
    """The glitch's jump must not stretch the distance the energy per metre (and so the
    remaining range) is taken over, mark area as sensed, or move the tour progress on."""
    ctx, plan = mission
    plain = MissionSession(ctx, plan, **KW)
    plain.feed(batch(0.0, HOME))
    reference = plain.feed(batch(20.0, (1.2, 1.0)))
    session = MissionSession(ctx, plan, **KW)
    first = session.feed(batch(0.0, HOME))
    glitch = session.feed(batch(10.0, xy))
    assert glitch.covered_m2 == first.covered_m2 and session._progress == 0
    assert glitch.energy_used_J == pytest.approx(first.energy_used_J + 9.0 * 10)
    after = session.feed(batch(20.0, (1.2, 1.0)))
    assert after.energy_used_J == pytest.approx(reference.energy_used_J)
    assert after.remaining_range_m < 1.5 * reference.remaining_range_m


@pytest.mark.timeout(300)
@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(x=st.floats(-1e6, 1e6), y=st.floats(-1e6, 1e6))
def test_any_position_is_refused_flagged_or_free(mission, x, y):
    """Refused iff more than 10 m beyond the box; flagged iff on the map but not free."""
    ctx, plan = mission
    session = MissionSession(ctx, plan, **KW)
    off = max(-x, x - 8.0, -y, y - 6.0, 0.0)
    try:
        d = session.feed(batch(0.0, (x, y), n=2))
    except InputError as exc:
        assert off > 10.0 and f"({x:g}, {y:g}) m" in str(exc)
        return
    assert off <= 10.0
    if bool(ctx.world.is_free(x, y)):
        assert d.action in ACTIONS and d.action not in FLAGS
    else:
        assert is_flag(d), d


# --- B: energy and time, Python API -------------------------------------------------------
def test_negative_power_cannot_fill_the_battery_beyond_full(mission):
    ctx, plan = mission
    session = MissionSession(ctx, plan, **KW)
    d = session.feed(batch(0.0, HOME, power_W=-500.0))
    assert d.energy_used_J == 0.0
    assert d.homing_margin_J <= d.energy_available_J
    assert d.remaining_range_m < math.inf
    # 9 W over the 10 s since the last sample is used from full, however much was
    # regenerated before; then 1 W regenerated over 10 s gives 10 J back
    d = session.feed(batch(10.0, HOME, power_W=9.0))
    assert d.energy_used_J == pytest.approx(9.0 * 10)
    d = session.feed(batch(20.0, HOME, power_W=-1.0))
    assert d.energy_used_J == pytest.approx(9.0 * 10 - 1.0 * 10)


@pytest.mark.parametrize("t", [-5.0, -1e-3, -1e9])
def test_negative_time_is_refused(mission, t):
    ctx, plan = mission
    session = MissionSession(ctx, plan, **KW)
    with pytest.raises(InputError, match="t_s is negative at row 0"):
        session.feed([{"t_s": t, "power_W": 9.0, "x_m": 1.0, "y_m": 1.0}])
    session.feed(batch(0.0, HOME))
    with pytest.raises(InputError, match="t_s does not increase"):
        session.feed(batch(1.0, HOME))  # back in time against the previous batch


def running_clamp(powers, times) -> float:
    """Reference: the battery's energy used, sample by sample, never below 0."""
    used, last = 0.0, None
    for p, t in zip(powers, times):
        used = max(0.0, used + p * (0.0 if last is None else t - last))
        last = t
    return used


@pytest.mark.timeout(300)
@settings(max_examples=30, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(batches=st.lists(st.lists(st.tuples(st.floats(-2000, 2000), st.floats(0.01, 30),
                                           st.floats(0, 8), st.floats(0, 6)),
                                 min_size=1, max_size=6), min_size=1, max_size=5))
def test_energy_used_never_negative_and_spare_never_above_the_battery(mission, batches):
    ctx, plan = mission
    session = MissionSession(ctx, plan, **KW)
    t, powers, times = 0.0, [], []
    for rows in batches:
        frame = []
        for power, dt, x, y in rows:
            t += dt
            frame.append({"t_s": t, "power_W": power, "x_m": x, "y_m": y})
            powers.append(power)
            times.append(t)
        d = session.feed(pd.DataFrame(frame))
        assert d.energy_used_J >= 0.0
        assert d.energy_used_J == pytest.approx(running_clamp(powers, times), rel=1e-9, abs=1e-6)
        assert not d.homing_margin_J > d.energy_available_J  # NaN under a flag


# --- HTTP ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def http(tmp_path_factory):
    pytest.importorskip("fastapi")
    pytest.importorskip("httpx")
    from fastapi.testclient import TestClient

    from orange_plan.service.app import create_app

    db = tmp_path_factory.mktemp("inputs") / "missions.sqlite"
    with TestClient(create_app(db, warm_up=False, token_from_env=False)) as c:
        yield c


def new_mission(c) -> str:
    r = c.post("/missions", json={"scenario": "rusti_v1_box", "n_vertices": 300})
    assert r.status_code == 201, r.text
    return r.json()["mission_id"]


@pytest.mark.parametrize("xy", OFF_MAP[:3])
def test_http_off_map_position_is_422_naming_it(http, xy):
    mid = new_mission(http)
    assert http.post(f"/missions/{mid}/telemetry",
                     json={"samples": batch(0.0, HOME)}).status_code == 200
    r = http.post(f"/missions/{mid}/telemetry", json={"samples": batch(10.0, xy)})
    assert r.status_code == 422, r.text
    assert f"({xy[0]:g}, {xy[1]:g}) m" in r.json()["detail"]
    live = http.get(f"/missions/{mid}/live").json()
    assert live["batches"] == 1 and live["position_xy_m"] == pytest.approx(HOME)


@pytest.mark.parametrize("xy", [IN_OBSTACLE[0], PAST_BOUNDARY[0]])
def test_http_position_in_obstacle_is_a_flagged_decision(http, xy):
    mid = new_mission(http)
    r = http.post(f"/missions/{mid}/telemetry", json={"samples": batch(0.0, xy)})
    assert r.status_code == 200, r.text
    d = r.json()
    assert d["action"] in FLAGS and "not where the map says" in d["reason"]
    assert d["energy_to_home_J"] is None and d["remaining_range_m"] is None


def test_http_negative_power_and_time(http):
    mid = new_mission(http)
    r = http.post(f"/missions/{mid}/telemetry",
                  json={"samples": batch(0.0, HOME, power_W=-500.0)})
    assert r.status_code == 200, r.text
    d = r.json()
    assert d["energy_used_J"] == 0.0 and d["homing_margin_J"] <= d["energy_available_J"]
    r = http.post(f"/missions/{mid}/telemetry",
                  json={"samples": [{"t_s": -3.0, "power_W": 9.0, "x_m": 1.0, "y_m": 1.0}]})
    assert r.status_code == 422 and "negative" in r.json()["detail"]


# --- CLI: the commands that read positions from a recording --------------------------------
@pytest.fixture(scope="module")
def far_recording(tmp_path_factory, mission):
    """A short simulated drive in the lab box, moved 100 km east."""
    ctx, _ = mission
    route = Route(np.array([[1.0, 1.0], [2.0, 1.0], [2.0, 1.5]]), np.full(3, 0.3), "probe")
    frame = simulate(ctx, route, seed=0).frame
    frame["x_m"] = frame["x_m"] + 1e5
    return write_recording(frame, tmp_path_factory.mktemp("far") / "far.csv")


@pytest.mark.parametrize("command", ["calibrate", "predict", "diagnose"])
def test_cli_refuses_a_recording_off_the_map(far_recording, command):
    code, _, err = run_cli(command, far_recording, "--scenario", SCENARIO)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, err
    assert "outside the map's boundary box" in lines[0] and "(100001, 1) m" in lines[0]
