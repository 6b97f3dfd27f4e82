"""``orange-plan serve``: the HTTP API with FastAPI's TestClient (no network, no browser).

A mission on ``scenarios/rusti_v1_box.toml`` (small lab box) with a 300-vertex roadmap plans
in about a second; the tests share one where they can.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import shapely
from conftest import REPO, run_cli
from test_cli_plan import check_plan_file

pytest.importorskip("fastapi")
pytest.importorskip("httpx")
from fastapi.testclient import TestClient

from orange_plan.commands.serve import check_bind, is_loopback
from orange_plan.errors import InputError
from orange_plan.scenario import load_scenario
from orange_plan.service.app import create_app
from orange_plan.service.limits import Limits

SCENARIO = "rusti_v1_box"
N_VERTICES = 300
HOME = (1.0, 1.0)  # lab_box.geojson's home


def client(db, **kwargs) -> TestClient:
    kwargs.setdefault("token_from_env", False)
    return TestClient(create_app(db, warm_up=False, **kwargs))


def create(c: TestClient, **body) -> dict:
    body = {"scenario": SCENARIO, "n_vertices": N_VERTICES, **body}
    r = c.post("/missions", json=body, headers=getattr(c, "auth", {}))
    assert r.status_code == 201, r.text
    return r.json()


def samples(t0: float, n: int, x0: float, y0: float, dx: float = 0.1, power_W: float = 9.0):
    """``n`` samples 1 s apart driving east from (x0, y0)."""
    return [{"t_s": t0 + i, "power_W": power_W, "x_m": x0 + dx * i, "y_m": y0}
            for i in range(1, n + 1)]


def one_line_detail(r) -> str:
    detail = r.json()["detail"]
    assert isinstance(detail, str) and detail and "\n" not in detail, r.text
    return detail


@pytest.fixture(scope="module")
def db(tmp_path_factory):
    return tmp_path_factory.mktemp("service") / "missions.sqlite"


@pytest.fixture(scope="module")
def mission(db):
    """A mission that has flown 20 s (two batches), had a map update and a replan."""
    with client(db) as c:
        created = create(c)
        mid = created["mission_id"]
        r1 = c.post(f"/missions/{mid}/telemetry", json={"samples": samples(0.0, 10, *HOME)})
        r2 = c.post(f"/missions/{mid}/telemetry",
                    json={"samples": samples(10.0, 10, HOME[0] + 1.0, HOME[1])})
        upd = c.post(f"/missions/{mid}/map", json={"obstacles": [
            {"type": "Polygon", "coordinates": [POSTED]}]})
        replan = c.post(f"/missions/{mid}/replan")
        view = {
            "created": created, "feed": [r1, r2], "map": upd, "replan": replan,
            "status": c.get(f"/missions/{mid}").json(),
            "decision": c.get(f"/missions/{mid}/decision").json(),
            "plan": c.get(f"/missions/{mid}/plan").json(),
            "live": c.get(f"/missions/{mid}/live").json(),
            "map_doc": c.get(f"/missions/{mid}/map").json(),
        }
    return mid, view


def test_create_mission_plans_a_spec_tour(db):
    with client(db) as c:
        created = create(c)
        assert created["scenario"] == SCENARIO and created["plan_version"] == 1
        assert created["decision"]["action"] == "continue"
        assert created["decision"]["homing_margin_J"] > 0
        r = c.get(f"/missions/{created['mission_id']}/plan")
        assert r.status_code == 200 and r.headers["content-type"] == "application/geo+json"
        check_plan_file(r.json(), HOME)
        assert created["mission_id"] in [m["mission_id"]
                                         for m in c.get("/missions").json()["missions"]]


def test_telemetry_returns_decision_and_moves_robot(mission):
    _mid, v = mission
    first, second = (r.json() for r in v["feed"])
    assert all(r.status_code == 200 for r in v["feed"])
    for d in (first, second):
        assert d["action"] in ("continue", "replan", "return_home")
        assert set(d) >= {"reason", "homing_margin_J", "return_probability", "energy_used_J",
                          "energy_to_home_J", "reserve_J", "remaining_range_m", "covered_m2"}
    # 9 W over the 9 s and then 19 s between the first sample and the last
    assert first["energy_used_J"] == pytest.approx(9.0 * 9, rel=1e-6)
    assert second["energy_used_J"] == pytest.approx(9.0 * 19, rel=1e-6)
    assert second["position_xy_m"] == pytest.approx([HOME[0] + 2.0, HOME[1]])
    assert second["time_s"] == 20.0
    live = v["live"]
    assert live["samples"] == 20 and live["batches"] == 2
    assert live["trail_xy_m"][-1] == pytest.approx([HOME[0] + 2.0, HOME[1]])
    assert live["covered"]["type"] in ("Polygon", "MultiPolygon")
    assert v["decision"]["position_xy_m"] == live["position_xy_m"]


POSTED = [[5, 4], [6, 4], [6, 5], [5, 5], [5, 4]]  # the obstacle the mission fixture posts


def test_a_tour_after_a_map_update_keeps_the_robot_radius_from_the_new_obstacle(mission):
    radius = load_scenario(REPO / "scenarios" / f"{SCENARIO}.toml").robot.radius_m
    assert radius > 0
    tour = next(f for f in mission[1]["plan"]["features"] if f["properties"]["kind"] == "tour")
    path = shapely.LineString(tour["geometry"]["coordinates"])
    assert path.distance(shapely.Polygon(POSTED)) >= radius - 1e-6


def test_a_map_update_too_near_home_names_the_distance(db):
    with client(db) as c:
        mid = create(c)["mission_id"]
        near = [[1.1, 0.5], [1.5, 0.5], [1.5, 1.5], [1.1, 1.5], [1.1, 0.5]]  # 0.1 m east of home
        r = c.post(f"/missions/{mid}/map", json={"obstacles": [
            {"type": "Polygon", "coordinates": [near]}]})
        assert r.status_code == 422, r.text
        detail = one_line_detail(r)  # the robot is at home: its position is named first
        assert "at (1, 1) m is 0.1 m from the nearest obstacle" in detail, detail
        assert c.get(f"/missions/{mid}").json()["map_updates"] == 0


def test_map_update_and_replan_give_a_new_plan(mission):
    _mid, v = mission
    assert v["map"].status_code == 200, v["map"].text
    assert v["replan"].status_code == 200, v["replan"].text
    assert v["status"]["map_updates"] == 1
    assert v["status"]["plan_version"] == 3  # first plan, map update's replan, replan
    kinds = [(f["properties"]["kind"], f["properties"].get("update", False))
             for f in v["map_doc"]["features"]]
    assert ("obstacle", True) in kinds and ("boundary", False) in kinds
    plan = v["plan"]
    tour = next(f for f in plan["features"] if f["properties"]["kind"] == "tour")
    xy = np.asarray(tour["geometry"]["coordinates"])
    assert xy[0] == pytest.approx([HOME[0] + 2.0, HOME[1]])  # from where the robot is
    assert xy[-1] == pytest.approx(HOME)
    assert min(tour["properties"]["margin_J"]) >= 0
    assert tour["properties"]["energy_used_J"][0] == pytest.approx(171.0, rel=1e-6)
    assert {len(tour["properties"][k]) for k in
            ("t_s", "speed_mps", "energy_used_J", "energy_to_home_J", "margin_J")} == {len(xy)}


def test_restart_restores_the_mission_and_its_samples(db, mission):
    mid, v = mission
    with client(db) as c:  # a new app on the same database: a restart
        status = c.get(f"/missions/{mid}").json()
        assert status["samples"] == 20 and status["batches"] == 2
        assert status["map_updates"] == 1 and status["plan_version"] == 3
        assert c.get(f"/missions/{mid}/plan").json() == v["plan"]
        decision = c.get(f"/missions/{mid}/decision").json()
        for key in ("action", "energy_used_J", "time_s", "position_xy_m", "homing_margin_J"):
            assert decision[key] == pytest.approx(v["decision"][key]), key
        assert c.get(f"/missions/{mid}/live").json()["trail_xy_m"] == v["live"]["trail_xy_m"]
        # and it carries on: time must go on from the last acknowledged sample
        r = c.post(f"/missions/{mid}/telemetry", json={"samples": samples(5.0, 2, *HOME)})
        assert r.status_code == 422 and "t_s does not increase" in one_line_detail(r)


def test_warm_up_rebuilds_missions_at_start(db, mission):
    mid, _ = mission
    app = create_app(db, token_from_env=False, warm_up=True)
    with TestClient(app):
        registry = app.state.registry
        for thread in [t for t in __import__("threading").enumerate()
                       if t.name == "orange-plan-replay"]:
            thread.join(timeout=60)
        assert mid in registry._live


def test_inline_scenario_with_map_from_maps_folder(tmp_path):
    text = (REPO / "scenarios" / f"{SCENARIO}.toml").read_text()
    with client(tmp_path / "m.sqlite") as c:
        for map_value in ("../maps/lab_box.geojson", "lab_box", "maps/lab_box.geojson"):
            toml = re.sub(r'(?m)^map = .*$', f'map = "{map_value}"', text)
            r = c.post("/missions", json={"scenario_toml": toml, "n_vertices": N_VERTICES})
            assert r.status_code == 201, r.text
            assert r.json()["inline_scenario"] is True
        # a restart rebuilds an inline mission from the stored text
        mid = r.json()["mission_id"]
    with client(tmp_path / "m.sqlite") as c:
        assert c.get(f"/missions/{mid}").json()["scenario"] == SCENARIO


@pytest.mark.parametrize("map_value", ["/etc/passwd", "../../etc/passwd", "../scenarios/x",
                                       "..", "nope", "lab_box/../../x"])
def test_inline_scenario_cannot_read_other_files(tmp_path, map_value):
    text = (REPO / "scenarios" / f"{SCENARIO}.toml").read_text()
    toml = re.sub(r'(?m)^map = .*$', f'map = "{map_value}"', text)
    with client(tmp_path / "m.sqlite") as c:
        r = c.post("/missions", json={"scenario_toml": toml})
        assert r.status_code == 422
        detail = one_line_detail(r)
        assert "maps/" in detail and str(REPO) not in detail


@pytest.mark.parametrize("name", ["../scenarios/rusti_v1_box", "/etc/passwd", "rusti_v1_bx",
                                  "a/b", ""])
def test_scenario_names_are_confined(tmp_path, name):
    with client(tmp_path / "m.sqlite") as c:
        r = c.post("/missions", json={"scenario": name})
        assert r.status_code == 422
        detail = one_line_detail(r)
        if name == "rusti_v1_bx":
            assert "did you mean 'rusti_v1_box'" in detail


def test_scenario_list_and_bad_scenario_toml(tmp_path):
    with client(tmp_path / "m.sqlite") as c:
        assert SCENARIO in c.get("/scenarios").json()["scenarios"]
        r = c.post("/missions", json={"scenario_toml": "name = [unclosed"})
        assert r.status_code == 422 and "not valid TOML" in one_line_detail(r)
        r = c.post("/missions", json={"scenario": SCENARIO, "scenario_toml": "x = 1"})
        assert r.status_code == 422 and "exactly one" in one_line_detail(r)
        text = (REPO / "scenarios" / f"{SCENARIO}.toml").read_text()
        r = c.post("/missions", json={"scenario_toml": text.replace("mass_kg", "mas_kg")})
        assert r.status_code == 422 and "mas_kg" in one_line_detail(r)


def test_auth_required_on_missions_when_token_set(tmp_path):
    with client(tmp_path / "m.sqlite", token="s3cret") as c:
        for method, path in (("get", "/missions"), ("post", "/missions"),
                             ("get", "/missions/x/plan"), ("post", "/missions/x/telemetry"),
                             ("get", "/scenarios")):
            r = getattr(c, method)(path)
            assert r.status_code == 401, path
            assert r.headers["www-authenticate"] == "Bearer"
            assert "bearer token" in one_line_detail(r)
        assert c.get("/missions", headers={"Authorization": "Bearer wrong"}).status_code == 401
        assert c.get("/missions", headers={"Authorization": "Basic s3cret"}).status_code == 401
        good = {"Authorization": "Bearer s3cret"}
        assert c.get("/missions", headers=good).status_code == 200
        assert c.get("/missions/x", headers=good).status_code == 404
        for public in ("/", "/docs", "/openapi.json", "/health", "/static/operator.js"):
            assert c.get(public).status_code == 200, public


def test_auth_off_without_token_and_token_from_env(tmp_path, monkeypatch):
    with client(tmp_path / "m.sqlite") as c:
        assert c.get("/missions").status_code == 200
        assert c.get("/health").json()["auth"] is False
    monkeypatch.setenv("ORANGE_PLAN_TOKEN", "from-env")
    with TestClient(create_app(tmp_path / "m.sqlite", warm_up=False)) as c:
        assert c.get("/missions").status_code == 401
        assert c.get("/missions", headers={"Authorization": "Bearer from-env"}).status_code == 200
    monkeypatch.setenv("ORANGE_PLAN_TOKEN", "  ")
    with pytest.raises(InputError, match="empty"):
        create_app(tmp_path / "m.sqlite")


def test_non_loopback_bind_needs_a_token(monkeypatch):
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.5")
    check_bind("127.0.0.1", None)
    check_bind("0.0.0.0", "tok")
    with pytest.raises(InputError, match="ORANGE_PLAN_TOKEN"):
        check_bind("0.0.0.0", None)
    monkeypatch.delenv("ORANGE_PLAN_TOKEN", raising=False)
    code, _, err = run_cli("serve", "--host", "0.0.0.0", "--port", "1")
    assert code == 2 and "ORANGE_PLAN_TOKEN" in err and len(err.strip().splitlines()) == 1


def test_oversized_bodies_get_413(tmp_path):
    limits = Limits(max_body_bytes=2048, max_samples=5, max_scenario_bytes=100)
    with client(tmp_path / "m.sqlite", limits=limits) as c:
        big = {"samples": [{"t_s": float(i), "power_W": 1.0, "x_m": 0.0, "y_m": 0.0}
                           for i in range(200)]}
        r = c.post("/missions/x/telemetry", json=big)
        assert r.status_code == 413 and "2048 bytes" in one_line_detail(r)

        def chunks():  # no Content-Length: read up to the limit, then refused
            for _ in range(100):
                yield b"x" * 100

        r = c.post("/missions/x/telemetry", content=chunks(),
                   headers={"content-type": "application/json"})
        assert r.status_code == 413
        r = c.post("/missions/x/telemetry", json={"samples": big["samples"][:6]})
        assert r.status_code == 413 and "at most 5" in one_line_detail(r)
        r = c.post("/missions", json={"scenario_toml": "#" * 200})
        assert r.status_code == 413


def test_bad_input_is_a_clear_4xx(db, mission):
    mid, _ = mission
    with client(db) as c:
        r = c.post(f"/missions/{mid}/telemetry", content=b'{"samples": [',
                   headers={"content-type": "application/json"})
        assert r.status_code == 400 and "malformed JSON" in one_line_detail(r)
        r = c.get("/missions/doesnotexist/decision")
        assert r.status_code == 404 and "doesnotexist" in one_line_detail(r)
        cases = [
            ({"samples": [{"t_s": 100.0, "x_m": 1, "y_m": 1}]}, "power_W"),
            ({"samples": [{"t_s": "soon", "power_W": 1, "x_m": 1, "y_m": 1}]}, "t_s"),
            ({"samples": [{"power_W": 1, "x_m": 1, "y_m": 1}]}, "t_s"),
            ({"samples": []}, "samples"),
            ({"samples": "all of them"}, "samples"),
            ({"samples": [{"t_s": 1e9, "power_W": 1, "x_m": 1e308, "y_m": 0}]}, "x_m"),
            ({"samples": [{"t_s": 100.0, "power_W": 1, "x_m": 1, "y_m": 1}], "x": 1}, "x"),
        ]
        for body, word in cases:
            r = c.post(f"/missions/{mid}/telemetry", json=body)
            assert r.status_code == 422, (body, r.text)
            assert word in one_line_detail(r), (body, r.text)
        r = c.post(f"/missions/{mid}/map", json={"obstacles": [{"type": "Polygon",
                                                                "coordinates": [[[0, 0]]]}]})
        assert r.status_code == 422 and "obstacles[0]" in one_line_detail(r)
        r = c.post(f"/missions/{mid}/map", json={})
        assert r.status_code == 422
        # a keep-out over home is refused, and nothing of it is stored
        r = c.post(f"/missions/{mid}/map", json={"no_go": [
            {"type": "Polygon", "coordinates": [[[0.5, 0.5], [1.5, 0.5], [1.5, 1.5],
                                                 [0.5, 1.5], [0.5, 0.5]]]}]})
        assert r.status_code == 422 and "home" in one_line_detail(r)
        assert c.get(f"/missions/{mid}").json()["map_updates"] == 1


FUZZ = [b"", b"null", b"[]", b"0", b'"x"', b"{", b"{}", b'{"samples": null}',
        b'{"samples": [null]}', b'{"samples": [[]]}', b'{"samples": [{"t_s": null}]}',
        b'{"samples": [{"t_s": 1e400, "power_W": 1, "x_m": 0, "y_m": 0}]}',
        b'{"samples": [{"t_s": NaN, "power_W": 1, "x_m": 0, "y_m": 0}]}',
        b'{"samples": [{"t_s": 1e9, "power_W": -1e308, "x_m": 1e308, "y_m": -1e308}]}',
        b'{"samples": [{"t_s": 1e9, "power_W": 1, "x_m": 0, "y_m": 0, "surface": 3}]}',
        b'{"samples": [{"t_s": 1e9, "power_W": true, "x_m": 0, "y_m": 0}]}',
        b'{"samples": [{"t_s": 1e9, "power_W": 1, "x_m": {"a": 1}, "y_m": 0}]}',
        b'{"obstacles": [{"type": "Point", "coordinates": [1, 2]}]}',
        b'{"obstacles": [{"type": "Polygon", "coordinates": "x"}]}',
        b'{"obstacles": [{"type": "Polygon", "coordinates": [[[0,0],[9,9],[0,9],[9,0],[0,0]]]}]}',
        b'{"no_go": [{"type": "MultiPolygon", "coordinates": [[[[1e308, 0], [0, 1], [1, 1]]]]}]}',
        b'{"obstacles": [{}], "replan": "maybe"}',
        b'{"scenario": 5}', b'{"scenario": "x", "n_vertices": -3}',
        b'{"scenario_toml": "map = 3"}', b'{"scenario_toml": "map = \\"lab_box\\"\\n[robot]"}',
        b'{"scenario": "rusti_v1_box", "n_vertices": 1e10}',
        "{\"scenario\": \"\u00e9\u00e9\"}".encode(), b"\xff\xfe\x00", b'{"a":' * 500]


def test_fuzz_malformed_bodies_never_5xx(tmp_path):
    db = tmp_path / "fuzz.sqlite"  # its own mission: a fuzz body may well be accepted
    with client(db) as c:
        mid = create(c)["mission_id"]
    paths = ["/missions", f"/missions/{mid}/telemetry", f"/missions/{mid}/map",
             "/missions/nope/telemetry", "/missions/nope/replan?x=1"]
    with client(db, limits=Limits(max_body_bytes=4096)) as c:
        for path in paths:
            for body in FUZZ:
                for ctype in ("application/json", "text/plain"):
                    r = c.post(path, content=body, headers={"content-type": ctype})
                    assert r.status_code < 500, (path, body, r.status_code, r.text)
                    if r.status_code >= 400:
                        one_line_detail(r)
        for path in (f"/missions/{mid}/plan/x", "/missions/%00", "/missions/" + "a" * 3000):
            assert c.get(path).status_code < 500


def test_delete_mission(tmp_path):
    with client(tmp_path / "m.sqlite") as c:
        mid = create(c)["mission_id"]
        assert c.delete(f"/missions/{mid}").status_code == 204
        assert c.get(f"/missions/{mid}").status_code == 404
        assert c.delete(f"/missions/{mid}").status_code == 404


def test_openapi_and_offline_docs(tmp_path):
    with client(tmp_path / "m.sqlite") as c:
        spec = c.get("/openapi.json").json()
        assert {"/missions", "/missions/{mission_id}/telemetry", "/missions/{mission_id}/plan",
                "/missions/{mission_id}/map", "/missions/{mission_id}/replan",
                "/missions/{mission_id}/decision"} <= set(spec["paths"])
        html = c.get("/docs").text
        urls = re.findall(r'(?:src|href)=["\']([^"\']+)', html) + re.findall(
            r"url:\s*'([^']+)'", html)
        assert urls and all(u.startswith("/") for u in urls), urls
        for u in urls:
            assert c.get(u).status_code == 200, u
        page = c.get("/").text
        assert not re.search(r'(?:src|href)=["\'](?:https?:)?//', page)
        assert c.get("/static/operator.css").status_code == 200


def test_store_is_wal_and_events_are_stored(db, mission):
    import sqlite3

    mid, _ = mission
    con = sqlite3.connect(db)
    try:
        assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        kinds = [k for (k,) in con.execute(
            "SELECT kind FROM events WHERE mission_id=? ORDER BY seq", (mid,))]
    finally:
        con.close()
    assert kinds == ["telemetry", "telemetry", "map", "plan", "plan"]
    stored = json.loads(sqlite3.connect(db).execute(
        "SELECT payload FROM events WHERE mission_id=? AND seq=1", (mid,)).fetchone()[0])
    assert stored["samples"] == samples(0.0, 10, *HOME)


def test_bad_database_file_is_refused(tmp_path):
    bad = tmp_path / "not.sqlite"
    bad.write_text("this is not a database" * 100)
    with pytest.raises(InputError, match="mission database"):
        create_app(bad, token_from_env=False)


def test_planning_does_not_block_other_requests(tmp_path):
    """A mission being planned (seconds, in the worker threadpool) does not stop the server
    from answering others."""
    import socket
    import threading
    import time

    import httpx

    uvicorn = pytest.importorskip("uvicorn")
    app = create_app(tmp_path / "m.sqlite", token_from_env=False, warm_up=False)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    srv = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    server = threading.Thread(target=srv.run, daemon=True)
    server.start()
    while not srv.started:
        time.sleep(0.05)
    url = f"http://127.0.0.1:{port}"
    try:
        result = {}

        def plan():
            result["r"] = httpx.post(f"{url}/missions", timeout=300,
                                     json={"scenario": SCENARIO, "n_vertices": 10_000})
            result["planned"] = time.perf_counter()

        planning = threading.Thread(target=plan)
        planning.start()
        time.sleep(0.3)
        health = httpx.get(f"{url}/health", timeout=60)
        listed = httpx.get(f"{url}/missions", timeout=60)
        answered = time.perf_counter()
        planning.join()
        assert health.status_code == 200 and listed.status_code == 200
        # an order, not a duration: both answers came while the plan was still being made
        assert answered < result["planned"]
        assert result["r"].status_code == 201
    finally:
        srv.should_exit = True
        server.join(timeout=10)


def test_an_exact_resend_of_the_last_batch_gets_its_answer_again(tmp_path):
    """A robot whose answer was lost sends the same batch again: it was acknowledged (stored)
    already, so it gets the same answer and is not fed twice, before and after a restart;
    a different batch with old times is still refused."""
    db = tmp_path / "m.sqlite"
    batch = {"samples": samples(0.0, 10, *HOME)}
    with client(db) as c:
        mid = create(c)["mission_id"]
        first = c.post(f"/missions/{mid}/telemetry", json=batch)
        again = c.post(f"/missions/{mid}/telemetry", json=batch)
        assert first.status_code == again.status_code == 200
        assert again.json() == first.json()
        assert c.get(f"/missions/{mid}").json()["samples"] == 10
        other = c.post(f"/missions/{mid}/telemetry",
                       json={"samples": samples(0.0, 10, *HOME, power_W=5.0)})
        assert other.status_code == 422 and "t_s" in one_line_detail(other)
    with client(db) as c:  # restarted: rebuilt from the database
        again = c.post(f"/missions/{mid}/telemetry", json=batch)
        assert again.status_code == 200 and again.json() == first.json()
        assert c.get(f"/missions/{mid}").json()["samples"] == 10


def test_a_created_mission_is_frozen_out_of_full_collections(tmp_path):
    """A mission's roadmap and plan are frozen after creation (``settle_heap``), so the
    garbage collector's full passes, which run in the middle of telemetry requests, no
    longer walk them (the p99 of ``bench service`` was those passes)."""
    import gc

    gc.unfreeze()
    try:
        with client(tmp_path / "m.sqlite") as c:
            create(c)
            assert gc.get_freeze_count() > 10_000
    finally:
        gc.unfreeze()


KEEP_A_MISSION = """
import sys
from orange_plan.context import load_context
from orange_plan.service.missions import SessionKind, settle_heap
session = SessionKind.new(load_context(sys.argv[1]), n_vertices=200, seed=0)
settle_heap()  # what the service does after every mission it makes
"""


@pytest.mark.parametrize("how", ["service mission", "cli plan"])
def test_a_process_that_planned_exits_without_leak_reports(tmp_path, how):
    """OMPL's bindings (nanobind) report every object of theirs alive at exit; a process
    that planned, as the service does or as ``plan`` does, must leave none behind."""
    import os
    import subprocess
    import sys

    scenario = str(REPO / "scenarios" / "rusti_v1_box.toml")
    if how == "cli plan":
        args = ["-m", "orange_plan.cli", "plan", scenario, "--vertices", "300",
                "-o", str(tmp_path / "plan.geojson")]
    else:
        args = ["-c", KEEP_A_MISSION, scenario]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env,
                          cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "leaked" not in done.stderr, done.stderr[:400]
