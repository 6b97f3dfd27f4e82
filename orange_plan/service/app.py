"""The HTTP API (FastAPI): missions, telemetry, decisions, map updates, replans, plans.

Planning runs while the request waits, in a planning worker process within the request's
memory and time budget (``service.worker``; over it: 422). The endpoints are plain ``def``
functions, so FastAPI runs them in its worker threadpool and the event loop stays free (the
operator page and other missions keep being served while one mission plans). Creating a
mission, a map update with ``replan`` and a replan answer when the new plan is ready, after
some seconds.
"""

from __future__ import annotations

import hmac
import json
import math
import os
from contextlib import asynccontextmanager
from importlib import resources
from pathlib import Path
from typing import Any

from fastapi import Depends, FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field
from starlette.exceptions import HTTPException as StarletteHTTPException

from orange_plan import __version__
from orange_plan.errors import InputError, NamedInputError, OrangeError, plain_message
from orange_plan.limits import MAX_ROADMAP_VERTICES
from orange_plan.service.limits import BodySizeLimit, Limits
from orange_plan.service.missions import (
    MissionNotFound,
    MissionRegistry,
    MissionUnavailable,
    count_vertices,
    live_view,
    map_geojson,
    status,
)
from orange_plan.service.scenarios import ScenarioLibrary
from orange_plan.service.store import Store
from orange_plan.service.worker import PlannerBusy, PlannerFailed, Planners
from orange_plan.telemetry.recording import NUMERIC_COLUMNS, TEXT_COLUMNS

TOKEN_ENV = "ORANGE_PLAN_TOKEN"
STATIC = Path(str(resources.files("orange_plan.service") / "static"))


def swagger_assets_dir() -> Path:
    """Swagger UI's bundle and stylesheet, shipped by the ``fastapi-offline`` wheel."""
    import fastapi_offline

    return Path(fastapi_offline.__file__).parent / "static"


UNAUTHORISED = ("missing or wrong bearer token: send 'Authorization: Bearer <token>' (the "
                "server's ORANGE_PLAN_TOKEN)")
PROTECTED = ("/missions", "/scenarios")
"""Path prefixes that need the token (the page, docs, schema, health and static files do
not: they hold no mission data)."""


class BearerFirst:
    """Pure ASGI: a request to a protected path without the right bearer token gets 401
    before anything else happens (its body is neither read nor parsed, so an unauthorised
    client cannot make the server parse megabytes of JSON, and gets 401, not 400/422/413)."""

    def __init__(self, app, token: str):
        self.app = app
        self.token = token.encode()

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or not _protected(scope.get("path", "")):
            await self.app(scope, receive, send)
            return
        given = b""
        for name, value in scope.get("headers", ()):
            if name == b"authorization":
                given = value
        scheme, _, credentials = given.partition(b" ")
        if scheme.lower() == b"bearer" and hmac.compare_digest(credentials.strip(), self.token):
            await self.app(scope, receive, send)
            return
        payload = json.dumps({"detail": UNAUTHORISED}).encode()
        await send({"type": "http.response.start", "status": 401,
                    "headers": [(b"content-type", b"application/json"),
                                (b"content-length", str(len(payload)).encode()),
                                (b"www-authenticate", b"Bearer")]})
        await send({"type": "http.response.body", "body": payload})


def _protected(path: str) -> bool:
    return any(path == p or path.startswith(p + "/") for p in PROTECTED)


# --- request bodies ------------------------------------------------------------------------
class MissionCreate(BaseModel):
    """Start a mission: a scenario by name or as TOML text, and the planner's roadmap options."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={
        "examples": [{"scenario": "rusti_v1_box", "n_vertices": 1000, "seed": 0}]})
    scenario: str | None = Field(None, max_length=100,
                                 description="name of a scenario in scenarios/ (no folders)")
    scenario_toml: str | None = Field(
        None, description="a scenario's TOML text; its 'map' names a map in maps/, "
                          "e.g. 'lab_box' or '../maps/lab_box.geojson'")
    n_vertices: int = Field(3000, ge=50, le=MAX_ROADMAP_VERTICES, description="roadmap vertices")
    seed: int = Field(0, ge=0, le=2**31 - 1, description="roadmap random seed")


class TelemetryBatch(BaseModel):
    """Telemetry samples (recording columns (docs/formats.md)), time-ordered, newer than any acknowledged one."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{"samples": [
        {"t_s": 0.0, "power_W": 12.0, "x_m": 1.0, "y_m": 1.0},
        {"t_s": 1.0, "power_W": 12.5, "x_m": 1.3, "y_m": 1.0}]}]})
    samples: list[dict[str, Any]] = Field(min_length=1, description="one object per sample")


class MapUpdate(BaseModel):
    """New keep-out areas (GeoJSON Polygon/MultiPolygon geometries in map metres)."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{
        "obstacles": [{"type": "Polygon",
                       "coordinates": [[[3, 3], [4, 3], [4, 4], [3, 4], [3, 3]]]}],
        "no_go": [], "replan": True}]})
    obstacles: list[dict[str, Any]] = Field(default_factory=list)
    no_go: list[dict[str, Any]] = Field(default_factory=list)
    replan: bool = Field(True, description="plan a new tour around them at once")


# --- responses -----------------------------------------------------------------------------
def finite(obj):
    """JSON has no NaN/inf: they become null."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite(v) for v in obj]
    if hasattr(obj, "item") and not isinstance(obj, (str, bytes)):  # numpy scalars
        return finite(obj.item())
    return obj


def reply(obj, status_code: int = 200, media_type: str = "application/json") -> Response:
    return Response(json.dumps(finite(obj), allow_nan=False), status_code=status_code,
                    media_type=media_type)


def one_line(text) -> str:
    return plain_message(text)


def error(status_code: int, detail: str, headers: dict | None = None) -> JSONResponse:
    return JSONResponse({"detail": one_line(detail)}, status_code=status_code, headers=headers)


def _one_line(status_code: int):
    """An exception handler answering ``status_code`` with the exception's message."""

    async def handler(request: Request, exc: Exception) -> JSONResponse:
        named = isinstance(exc, NamedInputError)
        return error(status_code, exc.named(FIELD_NAMES) if named else str(exc))

    return handler


# --- the app -------------------------------------------------------------------------------
def create_app(db: str | Path = "orange_plan.sqlite", *, token: str | None = None,
               token_from_env: bool = True, scenarios_dir=None, maps_dir=None,
               limits: Limits | None = None, sessions=None,
               warm_up: bool = True) -> FastAPI:
    """Build the service.

    Parameters
    ----------
    db : SQLite file of missions and events (created if missing; ``":memory:"`` for none)
    token : bearer token required on /missions... and /scenarios; None: read
        ``ORANGE_PLAN_TOKEN`` when ``token_from_env``; still None: no authentication
    scenarios_dir, maps_dir : the folders scenario and map names resolve in
        (default: the repository's ``scenarios/`` and ``maps/``)
    limits : request size limits
    sessions : how sessions are made and restored (default ``missions.SessionKind``)
    warm_up : rebuild stored missions in a background thread at start-up, and start the
        planning workers' forkserver (which loads the planner) at once

    Raises
    ------
    InputError
        An empty token, or a database file that is not a mission database.
    """
    if token is None and token_from_env:
        token = os.environ.get(TOKEN_ENV)
    if token is not None and not token.strip():
        raise InputError(f"{TOKEN_ENV} is set but empty: set a token or unset the variable")
    limits = limits or Limits()
    store = Store(db)
    registry = MissionRegistry(store, ScenarioLibrary(scenarios_dir, maps_dir), sessions,
                               Planners(limits.budget()))

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        if warm_up:
            registry.warm_up()
            registry.planners.start()
        yield
        store.close()

    app = FastAPI(
        title="orange-plan mission service", version=__version__, lifespan=lifespan,
        docs_url=None, redoc_url=None,
        description=(
            "Mid-mission replanning for battery-powered robots (ORangE energy model). Create a "
            "mission from a scenario, post telemetry batches, read the return-home decision, "
            "post map updates, replan, fetch the plan (plan GeoJSON (docs/formats.md)). The operator page is "
            "at `/`. When the server has a token (`ORANGE_PLAN_TOKEN`), every `/missions...` "
            "and `/scenarios` request needs `Authorization: Bearer <token>`."),
    )
    app.state.registry = registry
    app.state.store = store
    app.state.token = token
    app.state.limits = limits
    app.add_middleware(BodySizeLimit, max_bytes=limits.max_body_bytes)
    if token is not None:  # outermost: no body of an unauthorised request is read or parsed
        app.add_middleware(BearerFirst, token=token)
    _handlers(app)

    bearer = HTTPBearer(auto_error=False, description="the server's ORANGE_PLAN_TOKEN")

    def authorised(creds: HTTPAuthorizationCredentials | None = Depends(bearer)  # noqa: B008
                   ) -> None:
        # BearerFirst has refused a wrong token already; this declares the scheme in the
        # OpenAPI schema and guards an app used without the middleware
        if token is None:
            return
        given = (creds.credentials if creds is not None else "").encode()
        if creds is None or not hmac.compare_digest(given, token.encode()):
            raise HTTPException(401, UNAUTHORISED, headers={"WWW-Authenticate": "Bearer"})

    auth = [Depends(authorised)]

    # --- pages and docs (public: they hold no mission data) -------------------------------
    app.mount("/static", StaticFiles(directory=STATIC), name="static")
    app.mount("/docs-assets", StaticFiles(directory=swagger_assets_dir()), name="docs-assets")

    @app.get("/", include_in_schema=False)
    def operator_page():
        return FileResponse(STATIC / "index.html", media_type="text/html")

    @app.get("/docs", include_in_schema=False)
    def docs():
        return get_swagger_ui_html(
            openapi_url=app.openapi_url, title=app.title + " - API docs",
            swagger_js_url="/docs-assets/swagger-ui-bundle.js",
            swagger_css_url="/docs-assets/swagger-ui.css",
            swagger_favicon_url="/static/favicon.svg",
            swagger_ui_parameters={"validatorUrl": None})

    @app.get("/health", tags=["service"])
    def health() -> dict:
        """Liveness: always 200 while the server runs."""
        return {"status": "ok", "version": __version__, "auth": token is not None}

    # --- scenarios -------------------------------------------------------------------------
    @app.get("/scenarios", tags=["missions"], dependencies=auth)
    def scenarios() -> dict:
        """Scenario names a mission can be created from."""
        return {"scenarios": registry.library.names()}

    # --- missions --------------------------------------------------------------------------
    @app.post("/missions", tags=["missions"], status_code=201, dependencies=auth)
    def create_mission(body: MissionCreate):
        """Create a mission and plan its first tour (takes seconds; answers when planned)."""
        if body.scenario_toml is not None and \
                len(body.scenario_toml.encode()) > limits.max_scenario_bytes:
            raise HTTPException(413, f"scenario_toml is larger than {limits.max_scenario_bytes}"
                                     " bytes")
        source = registry.library.source(body.scenario, body.scenario_toml)
        live = registry.create(source, n_vertices=body.n_vertices, seed=body.seed)
        return reply(status(live), 201)

    @app.get("/missions", tags=["missions"], dependencies=auth)
    def list_missions():
        """Stored missions (ids, newest last)."""
        rows = [store.mission(i) for i in registry.ids()]
        return reply({"missions": [{"mission_id": r.id, "scenario": r.scenario_name,
                                    "created_s": r.created_s} for r in rows if r]})

    @app.get("/missions/{mission_id}", tags=["missions"], dependencies=auth)
    def get_mission(mission_id: str):
        """A mission's status: counters, last decision, plan summary."""
        return reply(status(registry.get(mission_id)))

    @app.delete("/missions/{mission_id}", tags=["missions"], status_code=204,
                dependencies=auth)
    def delete_mission(mission_id: str):
        """Forget a mission and everything stored about it."""
        registry.delete(mission_id)
        return Response(status_code=204)

    @app.post("/missions/{mission_id}/telemetry", tags=["missions"], dependencies=auth)
    def post_telemetry(mission_id: str, body: TelemetryBatch):
        """Feed a batch of samples; answers the decision once the batch is stored."""
        if len(body.samples) > limits.max_samples:
            raise HTTPException(413, f"{len(body.samples)} samples in one batch; at most "
                                     f"{limits.max_samples}: split the batch")
        check_samples(body.samples)
        return reply(registry.feed(mission_id, body.samples))

    @app.get("/missions/{mission_id}/decision", tags=["missions"], dependencies=auth)
    def get_decision(mission_id: str):
        """Continue, replan or return home, with the homing margin and return probability."""
        return reply(registry.decision(mission_id))

    @app.post("/missions/{mission_id}/map", tags=["missions"], dependencies=auth)
    def post_map(mission_id: str, body: MapUpdate):
        """Add obstacles / no-go zones; with ``replan`` the tour is planned around them."""
        if not body.obstacles and not body.no_go:
            raise InputError("a map update needs at least one of 'obstacles' and 'no_go'")
        if count_vertices(body.obstacles + body.no_go) > limits.max_geometry_vertices:
            raise HTTPException(413, "map update has more than "
                                     f"{limits.max_geometry_vertices} vertices")
        return reply(registry.update_map(mission_id, body.obstacles, body.no_go, body.replan))

    @app.get("/missions/{mission_id}/map", tags=["missions"], dependencies=auth)
    def get_map(mission_id: str):
        """The mission's map (feature kinds: docs/formats.md) with the posted updates (``update: true``)."""
        return reply(map_geojson(registry.get(mission_id)), media_type="application/geo+json")

    @app.post("/missions/{mission_id}/replan", tags=["missions"], dependencies=auth)
    def post_replan(mission_id: str):
        """Plan a new tour from the current position, energy and coverage (takes seconds)."""
        decision = registry.replan(mission_id)
        live = registry.get(mission_id)
        return reply({"decision": decision, "plan_version": live.plan_version,
                      "plan_summary": live.session.plan.summary})

    @app.get("/missions/{mission_id}/plan", tags=["missions"], dependencies=auth)
    def get_plan(mission_id: str):
        """The current plan as plan GeoJSON (docs/formats.md)."""
        live = registry.get(mission_id)
        with live.lock:
            doc = live.session.plan.to_geojson()
        return reply(doc, media_type="application/geo+json")

    @app.get("/missions/{mission_id}/live", tags=["missions"], dependencies=auth)
    def get_live(mission_id: str):
        """What the operator page polls: position, trail, covered area, decision, versions."""
        live = registry.get(mission_id)
        with live.lock:
            return reply(live_view(live))

    return app


MAX_ABS_VALUE = 1e12
"""No recording quantity (docs/formats.md) is larger in magnitude (beyond it, a stamp is epoch ms, a position is
not in a local metric frame); NaN passes here and the session reports it."""


def check_samples(samples: list[dict]) -> None:
    """Types of the recording columns (docs/formats.md); deeper checks (order, gaps) are the session's."""

    for i, sample in enumerate(samples):
        if "t_s" not in sample:
            raise InputError(f"samples[{i}]: missing 't_s'")
        for key, value in sample.items():
            if key in NUMERIC_COLUMNS and value is not None and (
                    isinstance(value, bool) or not isinstance(value, (int, float))):
                raise InputError(f"samples[{i}].{key}: expected a number, got {value!r:.40}")
            if key in NUMERIC_COLUMNS and isinstance(value, (int, float)) and \
                    not isinstance(value, bool) and abs(value) > MAX_ABS_VALUE:
                raise InputError(f"samples[{i}].{key}: {value:g} is out of range "
                                 f"(|value| <= {MAX_ABS_VALUE:g})")
            if key in TEXT_COLUMNS and value is not None and not isinstance(value, str):
                raise InputError(f"samples[{i}].{key}: expected a string, got {value!r:.40}")
            if isinstance(value, (dict, list)):
                raise InputError(f"samples[{i}].{key}: expected a number or a string")


FIELD_NAMES = {"start_xy": "the robot's position (x_m, y_m of the latest telemetry sample)",
               "energy_used_J": "the energy used (from the telemetry's power_W)",
               "time_used_s": "the mission time (t_s of the telemetry)"}
"""What the service calls each value a ``NamedInputError`` may name (never a CLI option)."""

EXPECTED = {"dict_type": "expected a JSON object", "list_type": "expected a JSON array",
            "int_type": "expected an integer", "int_parsing": "expected an integer",
            "int_from_float": "expected an integer", "float_type": "expected a number",
            "float_parsing": "expected a number", "bool_type": "expected true or false",
            "bool_parsing": "expected true or false", "string_type": "expected a string",
            "missing": "missing", "extra_forbidden": "not a field of this request"}
"""Our words for pydantic's error types (its own text names Python types)."""

GEOMETRY_FIELDS = ("obstacles", "no_go")
GEOMETRY_HINT = ('a GeoJSON Polygon or MultiPolygon object, e.g. {"type": "Polygon", '
                 '"coordinates": [[[x, y], ...]]}')


def field_path(loc) -> str:
    """``("body", "obstacles", 0)`` -> ``obstacles[0]``."""
    parts = [p for p in loc if p != "body"]
    text = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in parts).lstrip(".")
    return text or "body"


def in_our_words(problem: dict) -> str:
    """One request-validation problem, said without pydantic's Python vocabulary."""
    loc = [p for p in problem.get("loc", ()) if p != "body"]
    kind = problem.get("type", "")
    if loc and loc[0] in GEOMETRY_FIELDS and kind == "dict_type":
        return f"expected {GEOMETRY_HINT}"
    if kind in EXPECTED:
        got = problem.get("input")
        shown = "" if kind in ("missing", "extra_forbidden") else f", got {json.dumps(got)[:40]}"
        return EXPECTED[kind] + shown
    limits = problem.get("ctx") or {}
    for key, word in (("ge", ">="), ("gt", ">"), ("le", "<="), ("lt", "<")):
        if key in limits:
            return f"must be {word} {limits[key]}"
    unit = "character" if kind.startswith("string") else "item"
    for key, word in (("min_length", "needs at least"), ("max_length", "takes at most")):
        if key in limits:
            n = limits[key]
            return f"{word} {n} {unit}{'' if n == 1 else 's'}"
    return str(problem.get("msg", "invalid"))


def _handlers(app: FastAPI) -> None:
    """Every error is JSON ``{"detail": "one line"}``; bad input is 4xx, never 5xx."""

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError):
        errors = exc.errors()
        first = errors[0] if errors else {"loc": (), "msg": "invalid request"}
        if first.get("type") == "json_invalid":
            ctx = first.get("ctx") or {}
            return error(400, f"malformed JSON body: {ctx.get('error', first['msg'])}")
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        return error(422, f"{field_path(first.get('loc', ()))}: {in_our_words(first)}{more}")

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException):
        return error(exc.status_code, exc.detail, getattr(exc, "headers", None))

    # Our own errors by status; OrangeError that is not input is a request that cannot be met
    # (e.g. no tour keeps the homing constraint from here).
    answers = {MissionNotFound: 404, InputError: 422, MissionUnavailable: 503,
               PlannerBusy: 503, PlannerFailed: 503, OrangeError: 409}
    for kind, code in answers.items():
        app.add_exception_handler(kind, _one_line(code))

    @app.exception_handler(Exception)
    async def internal(request: Request, exc: Exception):
        return error(500, f"internal error: {type(exc).__name__}: {exc}")
