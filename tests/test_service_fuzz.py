"""Property-based API test: requests generated from the service's own OpenAPI schema
(schemathesis, hypothesis underneath) through FastAPI's TestClient, to every operation;
none may get a 5xx, and every error is one-line JSON ``{"detail": ...}``.

Path parameters are generated too (so mostly unknown missions, 404); half the cases on a
mission operation are sent to a real mission instead (a 300-vertex ``rusti_v1_box`` mission
created first), so that generated telemetry, map updates and replans reach the session (at
most ``REAL_PLANS`` of an operation that plans a tour). A
generated ``n_vertices`` is capped at 100 so that a valid mission (seconds of planning for
20 000 vertices) stays quick; the bounds themselves are checked in test_service.py.
Authentication: tests/test_service.py::test_auth_required_on_missions_when_token_set (401
with ``WWW-Authenticate: Bearer`` on every /missions... and /scenarios request without the
token or with a wrong one) and ::test_auth_off_without_token_and_token_from_env
(``ORANGE_PLAN_TOKEN`` read from the environment); ``test_generated_requests_without_token``
below repeats it on every generated operation.
"""

from __future__ import annotations

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")
pytest.importorskip("schemathesis")
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, settings

from orange_plan.service.app import create_app

TOKEN = "fuzz-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
MAX_VERTICES = 100


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    """A served app with a token and one real mission."""
    db = tmp_path_factory.mktemp("fuzz") / "fuzz.sqlite"
    app = create_app(db, token=TOKEN, warm_up=False)
    with TestClient(app, raise_server_exceptions=False) as c:
        r = c.post("/missions", json={"scenario": "rusti_v1_box", "n_vertices": 300},
                   headers=AUTH)
        assert r.status_code == 201, r.text
        yield c, r.json()["mission_id"]


def _schema():
    from orange_plan.service.app import create_app as make

    # the schema only: a throw-away in-memory app (no token: same operations and bodies)
    return schemathesis.openapi.from_asgi("/openapi.json", make(":memory:", warm_up=False,
                                                                   token_from_env=False))


schema = _schema()


def _send(client: TestClient, case, headers: dict):
    kwargs = case.as_transport_kwargs(base_url="")
    kwargs.pop("base_url", None)
    kwargs["headers"] = {**(kwargs.get("headers") or {}), **headers}
    method, url = kwargs.pop("method"), kwargs.pop("url")
    return client.request(method, url, **{k: v for k, v in kwargs.items()
                                          if k in ("headers", "params", "json", "content",
                                                   "data", "files") and v is not None})


REAL_PLANS = 4
"""Cases of one operation that plan a tour (a replan, a map update that replans) sent to the
real mission: past the first few they differ only in ids and obstacles that the session
refuses or plans around alike, and each costs a whole tour's planning (0.5-1 s; forty of
them made the slowest test of the suite)."""
_plans_sent: dict[str, int] = {}  # per operation


def _plans(case) -> bool:
    """Whether a case would plan a tour on the mission it is sent to."""
    if case.formatted_path.endswith("/replan"):
        return True
    body = case.body if isinstance(case.body, dict) else {}
    return case.formatted_path.endswith("/map") and body.get("replan", True) is not False


def _adapt(case, mid: str) -> None:
    """Send half the mission cases to the real mission (at most ``REAL_PLANS`` of an
    operation that plan a tour); cap generated roadmap sizes."""
    params = case.path_parameters or {}
    plans = _plans(case)
    if "mission_id" in params and case.method.upper() != "DELETE" and \
            hash(repr(case.body)) % 2 == 0 and \
            not (plans and _plans_sent.get(case.path, 0) >= REAL_PLANS):
        params["mission_id"] = mid
        _plans_sent[case.path] = _plans_sent.get(case.path, 0) + plans
    body = case.body
    if isinstance(body, dict) and isinstance(body.get("n_vertices"), int) and \
            body["n_vertices"] > MAX_VERTICES:
        body["n_vertices"] = MAX_VERTICES


def _check(response, case) -> None:
    assert response.status_code < 500, (case.method, case.formatted_path, case.body,
                                        response.status_code, response.text[:500])
    if response.status_code >= 400:
        detail = response.json()["detail"]
        assert isinstance(detail, str) and detail and "\n" not in detail, response.text


@schema.parametrize()
@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                 HealthCheck.filter_too_much])
def test_generated_requests_never_5xx(case, live):
    client, mid = live
    _adapt(case, mid)
    _check(_send(client, case, AUTH), case)


@schema.parametrize()
@settings(max_examples=5, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
def test_generated_requests_without_token(case, live):
    """With ORANGE_PLAN_TOKEN set, no generated request to a mission operation gets in
    without it (401), whatever its body."""
    client, mid = live
    _adapt(case, mid)
    r = _send(client, case, {"Authorization": "Bearer not-the-token"})
    wrong_method = case.method.upper() != case.operation.method.upper()  # a negative case: 405
    if case.formatted_path.startswith(("/missions", "/scenarios")) and not wrong_method:
        assert r.status_code == 401, (case.method, case.formatted_path, r.status_code)
        assert r.headers["www-authenticate"] == "Bearer"
    else:
        assert r.status_code < 500


def test_unauthorised_body_is_not_read(live):
    """Without the token a request is refused with 401 before its body is parsed: malformed
    JSON, a wrong type, or a body over the size limit all get 401, never 400/413/422."""
    client, mid = live
    for path in ("/missions", f"/missions/{mid}/telemetry", f"/missions/{mid}/map"):
        for body in (b'{"samples": [', b'{"samples": 3}', b"x" * (9 * 1024 * 1024)):
            for headers in ({}, {"Authorization": "Bearer wrong"},
                            {"Authorization": f"Basic {TOKEN}"}):
                r = client.post(path, content=body,
                                headers={"content-type": "application/json", **headers})
                assert r.status_code == 401, (path, body[:20], headers, r.status_code)
                assert r.headers["www-authenticate"] == "Bearer"
    r = client.post(f"/missions/{mid}/telemetry", headers=AUTH, json={"samples": [
        {"t_s": 1e6, "power_W": 5.0, "x_m": 1.0, "y_m": 1.0}]})
    assert r.status_code in (200, 422), r.text  # with the token it gets through
