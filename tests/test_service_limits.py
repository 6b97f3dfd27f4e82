"""The service under requests too big for it: sizes beyond ``orange_plan.limits`` are
refused with one line (422), planning runs in a worker process within a memory and time
budget (over it: 422, the worker stopped), and the other missions keep being served.

One ``rusti_v1_box`` mission (300 vertices) is created first and checked after every refusal.
"""

from __future__ import annotations

import json
import math

import pytest
from conftest import REPO
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytest.importorskip("fastapi")
pytest.importorskip("httpx")
from fastapi.testclient import TestClient

from orange_plan.limits import MAX_COVERAGE_LATTICE_POINTS, MAX_ROADMAP_VERTICES
from orange_plan.service.app import create_app
from orange_plan.service.worker import Budget, Planners

LAB_TOML = (REPO / "scenarios" / "rusti_v1_box.toml").read_text(encoding="utf-8")
RADIUS_LINE = "sensor_radius_m = 1.0 "
assert RADIUS_LINE in LAB_TOML
HOME = (1.0, 1.0)


def with_radius(value: str) -> str:
    """The lab scenario's TOML with another ``sensor_radius_m`` (TOML text: nan, inf ok)."""
    return LAB_TOML.replace(RADIUS_LINE, f"sensor_radius_m = {value} ")


def send(c: TestClient, method: str, path: str, body) -> object:
    """A request with a JSON body as Python writes it (NaN and Infinity included)."""
    return c.request(method, path, content=json.dumps(body).encode(),
                     headers={"content-type": "application/json"})


def clear_4xx(r, status: int | None = None) -> str:
    """A 4xx (or ``status``) whose body is one JSON line without a traceback."""
    assert 400 <= r.status_code < 500 if status is None else r.status_code == status, \
        (r.status_code, r.text[:300])
    assert "Traceback" not in r.text and "File \"" not in r.text, r.text
    detail = r.json()["detail"]
    assert isinstance(detail, str) and detail and "\n" not in detail, r.text
    return detail


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """A served app and one mission that has flown a few metres."""
    db = tmp_path_factory.mktemp("limits") / "missions.sqlite"
    with TestClient(create_app(db, warm_up=False, token_from_env=False),
                    raise_server_exceptions=False) as c:
        r = c.post("/missions", json={"scenario": "rusti_v1_box", "n_vertices": 300})
        assert r.status_code == 201, r.text
        mid = r.json()["mission_id"]
        r = c.post(f"/missions/{mid}/telemetry", json={"samples": [
            {"t_s": float(i), "power_W": 9.0, "x_m": HOME[0] + 0.1 * i, "y_m": HOME[1]}
            for i in range(5)]})
        assert r.status_code == 200, r.text
        yield c, mid


def still_served(c: TestClient, mid: str) -> None:
    """The first mission answers as before: status, decision, plan."""
    assert c.get("/health").status_code == 200
    status = c.get(f"/missions/{mid}")
    assert status.status_code == 200 and status.json()["samples"] == 5, status.text
    assert c.get(f"/missions/{mid}/decision").status_code == 200
    assert c.get(f"/missions/{mid}/plan").status_code == 200


def test_a_tiny_sensor_radius_is_refused_and_the_service_keeps_serving(served):
    """The inline scenario that grew the server to 24 GB: 422 at once, one line naming the
    setting and the limit."""
    c, mid = served
    r = c.post("/missions", json={"scenario_toml": with_radius("1e-9"), "n_vertices": 300})
    detail = clear_4xx(r, 422)
    assert "sensor_radius_m" in detail and f"{MAX_COVERAGE_LATTICE_POINTS:,}" in detail
    still_served(c, mid)


def test_vertices_beyond_the_limit_are_refused(served):
    c, mid = served
    for n in (MAX_ROADMAP_VERTICES + 1, 99_999_999, -1):
        detail = clear_4xx(c.post("/missions", json={"scenario": "rusti_v1_box",
                                                     "n_vertices": n}), 422)
        assert "n_vertices" in detail
    still_served(c, mid)


def resident_bytes() -> int:
    """This (the server's) process's resident memory [bytes]."""
    import os

    with open("/proc/self/statm", encoding="ascii") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def hog_memory(*_args):
    """A stand-in planner that asks for 8 GiB at once."""
    return len(bytearray(8 * 2**30))


def hog_time(*_args):
    """A stand-in planner that never finishes."""
    import time

    time.sleep(3600)


@pytest.mark.parametrize(("planner", "budget", "word"), [
    (hog_memory, Budget(memory_bytes=4 * 2**30, seconds=300.0, workers=1), "memory budget"),
    (hog_time, Budget(memory_bytes=4 * 2**30, seconds=1.0, workers=1), "time budget"),
])
def test_a_plan_over_its_budget_is_stopped_with_a_clear_4xx(served, monkeypatch, planner,
                                                            budget, word):
    """A plan that needs more memory or time than a request may use: its worker is stopped,
    the answer is 422 naming the budget, the server's memory does not grow, and the other
    mission is served and replans."""
    from orange_plan.service import missions

    c, mid = served
    registry = c.app.state.registry
    monkeypatch.setattr(registry, "planners", Planners(budget))
    for name in ("plan_first", "plan_again"):
        monkeypatch.setattr(missions, name, planner)
    before = resident_bytes()
    r = c.post("/missions", json={"scenario": "rusti_v1_box", "n_vertices": 300})
    assert word in clear_4xx(r, 422)
    r = c.post(f"/missions/{mid}/replan")
    assert word in clear_4xx(r, 422)
    assert resident_bytes() - before < 200 * 2**20  # the 8 GiB were asked for elsewhere
    still_served(c, mid)
    monkeypatch.undo()
    r = c.post(f"/missions/{mid}/replan")
    assert r.status_code == 200, r.text


def test_planners_are_worker_processes():
    """The planning budget's mechanism: a worker's failed allocation, a worker's timeout."""
    from orange_plan.service.worker import PlanningBudgetExceeded

    for planner, seconds, word in ((hog_memory, 60.0, "memory"), (hog_time, 1.0, "time")):
        planners = Planners(Budget(memory_bytes=256 * 2**20, seconds=seconds, workers=1))
        with pytest.raises(PlanningBudgetExceeded, match=f"{word} budget"):
            planners.run(planner)
    assert planners.run(math.hypot, 3.0, 4.0) == 5.0


# --- generated families of bad sizes and bad geometries ------------------------------------
TOML_RADII = st.one_of(
    st.floats(5e-324, 0.01).map(repr),  # tiny: over the coverage lattice limit (11 mm)
    st.floats(1e3, 1e300).map(repr),  # huge: one footprint larger than the free space
    st.sampled_from(["nan", "inf", "-inf", "0.0", "-1.0", "-1e-9", "1e999"]),
)
VERTICES = st.one_of(st.integers(MAX_ROADMAP_VERTICES + 1, 10**30),
                     st.integers(-(10**30), 49),
                     st.floats(allow_nan=True).filter(lambda v: not float(v).is_integer()),
                     st.sampled_from([None, "many", [300], {"n": 300}]))


def _bad_ring(base):
    """A ring broken one way: a non-finite or far coordinate, unclosed, moved out of the
    map, or too short."""
    x0, y0 = base
    square = [[x0, y0], [x0 + 1, y0], [x0 + 1, y0 + 1], [x0, y0 + 1], [x0, y0]]
    return st.one_of(
        st.sampled_from([math.nan, math.inf, -math.inf, 1e300, -1e12]).flatmap(
            lambda v: st.integers(0, 3).map(
                lambda k: [p if i != k else [v, p[1]] for i, p in enumerate(square)])),
        st.just(square[:-1]),
        st.floats(50, 1e6).map(lambda d: [[x + d, y] for x, y in square]),
        st.just(square[:2]),
        st.just([[x0, y0], [x0 + 1, y0 + 1], [x0 + 1, y0], [x0, y0 + 1], [x0, y0]]),
    )


BAD_GEOMETRIES = st.one_of(
    _bad_ring((5.0, 4.0)).map(lambda ring: {"type": "Polygon", "coordinates": [ring]}),
    _bad_ring((5.0, 4.0)).map(lambda ring: {"type": "MultiPolygon", "coordinates": [[ring]]}),
    st.sampled_from([{"type": "Point", "coordinates": [5, 4]},
                     {"type": "LineString", "coordinates": [[5, 4], [6, 5]]},
                     {"type": "Polygon", "coordinates": [[[5, 4]]]},
                     {"type": "Polygon", "coordinates": "x"}, {"type": "Polygon"}, {}]),
)


@settings(max_examples=30, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(radius=TOML_RADII, vertices=VERTICES)
def test_generated_bad_sizes_get_a_clear_4xx(served, radius, vertices):
    c, mid = served
    r = send(c, "POST", "/missions", {"scenario_toml": with_radius(radius), "n_vertices": 300})
    clear_4xx(r)
    r = send(c, "POST", "/missions", {"scenario": "rusti_v1_box", "n_vertices": vertices})
    clear_4xx(r)
    assert c.get(f"/missions/{mid}").status_code == 200


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(geometry=BAD_GEOMETRIES, kind=st.sampled_from(["obstacles", "no_go"]),
       replan=st.booleans())
def test_generated_bad_map_updates_get_a_clear_4xx(served, geometry, kind, replan):
    c, mid = served
    r = send(c, "POST", f"/missions/{mid}/map", {kind: [geometry], "replan": replan})
    detail = clear_4xx(r, 422)
    assert f"{kind}[0]" in detail or kind in detail
    assert c.get(f"/missions/{mid}").json()["map_updates"] == 0
