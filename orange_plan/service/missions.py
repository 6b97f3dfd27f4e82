"""Live missions: one ``MissionSession`` per stored mission, rebuilt from the store.

Every change follows the same order: validate, apply to the session under the mission's
lock, store the event(s) in one committed transaction, then answer. If the store fails, the
in-memory session is dropped so that the next request rebuilds it from what was stored.

Rebuilding (after a restart, or after such a failure) replays the mission through
``MissionSession.from_state``: the stored first plan, then every stored event in order
(telemetry batches fed again, map updates applied, the plans adopted by replans taken as
stored). Nothing is planned again, so the rebuilt session gives the same decisions and the
same plan as before the restart; replaying is fast (no planning), and
``MissionRegistry.warm_up`` does it for every mission in a background thread at start-up.
A request to a mission still being rebuilt waits for it.

Planning (a new mission's first tour, a replan) runs in a planning worker process
(``service.worker``), which answers with the plan's GeoJSON; the session then adopts it by
the same replay, with the plan as its last event.
"""

from __future__ import annotations

import atexit
import gc
import logging
import secrets
import threading
import time
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import shapely
from shapely.geometry import mapping, shape

from orange_plan.errors import InputError, OrangeError
from orange_plan.service.limits import Limits
from orange_plan.service.scenarios import ScenarioLibrary, ScenarioSource
from orange_plan.service.store import MissionRow, Store
from orange_plan.service.worker import Planners

if TYPE_CHECKING:
    from orange_plan.context import Context

log = logging.getLogger("orange_plan.service")

MAX_TRAIL_POINTS = 2000
"""The live view sends at most this many trail points (evenly decimated, last one kept)."""

SESSION_DEFAULTS = {"replan_margin_J": 0.0, "planner_kwargs": {"bitstar_legs": 0},
                    "memory_s": 300.0, "window_s": 300.0}
"""MissionSession options the service uses (stored with each mission for its replay)."""


class MissionNotFound(InputError):
    """No mission with that id."""


class MissionUnavailable(OrangeError):
    """A stored mission could not be rebuilt (not the client's fault)."""


def plan_first(library: ScenarioLibrary, source: ScenarioSource, n_vertices: int, seed: int,
               sessions) -> dict:
    """In a planning worker: a new mission's first plan (plan GeoJSON (docs/formats.md))."""
    session = sessions.new(library.context(source), n_vertices=n_vertices, seed=seed)
    return session.plan.to_geojson()


def plan_again(library: ScenarioLibrary, source: ScenarioSource, state: dict, sessions) -> dict:
    """In a planning worker: the session of ``state`` replanned from where it is now."""
    session = sessions.restore(library.context(source), state)
    return session.replan().to_geojson()


class SessionKind:
    """How sessions are made and restored (tests may pass another)."""

    @staticmethod
    def new(ctx: Context, *, n_vertices: int, seed: int):
        from orange_plan.planning.session import MissionSession

        return MissionSession(ctx, n_vertices=n_vertices, seed=seed, **_options())

    @staticmethod
    def restore(ctx: Context, state: dict):
        from orange_plan.planning.session import MissionSession

        return MissionSession.from_state(ctx, state)

    @staticmethod
    def state_version() -> int:
        from orange_plan.planning.session import STATE_VERSION

        return STATE_VERSION


def _options() -> dict:
    return {k: (dict(v) if isinstance(v, dict) else v) for k, v in SESSION_DEFAULTS.items()}


@dataclass
class LiveMission:
    """A mission's session and what the service counts about it."""

    row: MissionRow
    session: object
    lock: threading.RLock = field(default_factory=threading.RLock)
    samples: int = 0
    batches: int = 0
    map_updates: list = field(default_factory=list)
    plan_version: int = 1
    map_version: int = 0
    events: int = 0
    updated_s: float = field(default_factory=time.time)
    last_decision: dict | None = None
    last_batch: list | None = None
    """The last event's samples when it was a telemetry batch (an exact resend of it, after
    an answer that was lost on the way, gets that answer again)."""

    @property
    def ctx(self):
        return self.session.ctx


class MissionRegistry:
    """Creates, finds, changes and rebuilds missions.

    Parameters
    ----------
    store : the SQLite store
    library : where scenario names and maps are resolved
    sessions : how sessions are made and restored (default ``SessionKind``)
    planners : the worker processes that plan, within a request's budget (default: the
        budget of ``Limits()``)
    """

    def __init__(self, store: Store, library: ScenarioLibrary, sessions=None,
                 planners: Planners | None = None):
        self.store = store
        self.library = library
        self.sessions = sessions or SessionKind
        self.planners = planners or Planners(Limits().budget())
        self._live: dict[str, LiveMission] = {}
        self._loading: dict[str, threading.Lock] = {}
        self._guard = threading.Lock()

    # --- create / find -------------------------------------------------------------------
    def create(self, source: ScenarioSource, *, n_vertices: int, seed: int) -> LiveMission:
        """Load the scenario, plan the first tour (seconds, in a planning worker), store the
        mission."""
        self.library.context(source)  # a scenario that does not load is refused at once
        plan = self.planners.run(plan_first, self.library, source, n_vertices, seed,
                                 self.sessions, what="planning the first tour")
        row = MissionRow(id=secrets.token_hex(6), created_s=time.time(),
                         scenario_name=source.name, scenario_toml=source.toml_text,
                         inline=source.inline,
                         options={"n_vertices": n_vertices, "seed": seed, **_options()},
                         initial_plan=plan)
        session = self._restored(row, [])
        live = LiveMission(row, session)
        live.last_decision = decision_dict(session.decision())
        self.store.add_mission(row)
        with self._guard:
            self._live[row.id] = live
        settle_heap()
        return live

    def ids(self) -> list[str]:
        return self.store.mission_ids()

    def get(self, mission_id: str) -> LiveMission:
        """The live mission, rebuilt from the store first if needed."""
        live = self._live.get(mission_id)
        if live is not None:
            return live
        with self._guard:
            loading = self._loading.setdefault(mission_id, threading.Lock())
        with loading:
            live = self._live.get(mission_id)
            if live is not None:
                return live
            row = self.store.mission(mission_id)
            if row is None:
                raise MissionNotFound(f"no mission {mission_id!r}")
            live = self._rebuild(row)
            with self._guard:
                self._live[mission_id] = live
            settle_heap()
            return live

    def delete(self, mission_id: str) -> None:
        if not self.store.delete_mission(mission_id):
            raise MissionNotFound(f"no mission {mission_id!r}")
        with self._guard:
            self._live.pop(mission_id, None)

    def warm_up(self) -> threading.Thread:
        """Rebuild every stored mission in a background thread."""
        def run():
            for mission_id in self.ids():
                try:
                    self.get(mission_id)
                except Exception as exc:  # noqa: BLE001 - logged; requests report it again
                    log.error("mission %s could not be rebuilt: %s", mission_id, exc)

        thread = threading.Thread(target=run, name="orange-plan-replay", daemon=True)
        thread.start()
        return thread

    # --- changes -------------------------------------------------------------------------
    def feed(self, mission_id: str, samples: list[dict]) -> dict:
        """Feed one telemetry batch; the decision after it, once stored."""
        live = self.get(mission_id)
        with live.lock, self._untouched_unless_stored(live):
            if live.last_batch is not None and samples == live.last_batch:
                return live.last_decision  # acknowledged already: its answer was lost
            decision = live.session.feed(samples)
            live.samples += len(samples)
            live.batches += 1
            answer = self._commit(live, [("telemetry", {"samples": samples})], decision)
            live.last_batch = samples
            return answer

    def update_map(self, mission_id: str, obstacles: list, no_go: list, replan: bool) -> dict:
        """Add obstacles / no-go zones (GeoJSON geometries); the decision after it.

        The map update is stored even when the replan that follows it fails (the error then
        says so, and the next decision says ``replan``).
        """
        live = self.get(mission_id)
        with live.lock, self._untouched_unless_stored(live):
            decision = live.session.update_map(obstacles=obstacles, no_go=no_go, replan=False)
            live.map_updates += [("obstacle", g) for g in obstacles]
            live.map_updates += [("no_go", g) for g in no_go]
            live.map_version += 1
            events = [("map", {"obstacles": obstacles, "no_go": no_go})]
            if replan:
                try:
                    plan = self._replanned(live)
                except OrangeError as exc:
                    self._commit(live, events, live.session.decision())
                    raise type(exc)(f"the map update is stored, but no new tour: {exc}") \
                        from None
                events.append(("plan", plan))
                decision = live.session.decision()
            return self._commit(live, events, decision)

    def replan(self, mission_id: str) -> dict:
        """Plan a new tour from the robot's current state; the decision after it."""
        live = self.get(mission_id)
        with live.lock, self._untouched_unless_stored(live):
            plan = self._replanned(live)
            return self._commit(live, [("plan", plan)], live.session.decision())

    def decision(self, mission_id: str) -> dict:
        live = self.get(mission_id)
        with live.lock:
            live.last_decision = decision_dict(live.session.decision())
            return live.last_decision

    # --- internals -----------------------------------------------------------------------
    def _replanned(self, live: LiveMission) -> dict:
        """Replan in a planning worker and adopt the plan: the session is rebuilt from its
        state with the new plan as its last event (as a restart would rebuild it); the
        plan's GeoJSON is returned."""
        state = live.session.state_dict()
        plan = self.planners.run(plan_again, self.library, _source(live.row), state,
                                 self.sessions, what="replanning")
        live.session = self.sessions.restore(self.library.context(_source(live.row)),
                                             {**state, "events": [*state["events"],
                                                                  {"plan": plan}]})
        return plan

    def _restored(self, row: MissionRow, events: list) -> object:
        """The session of a stored mission, replayed from its first plan and ``events``."""
        ctx = self.library.context(_source(row))
        opts = row.options
        state = {"version": self.sessions.state_version(), "scenario": ctx.scenario.name,
                 "n_vertices": opts["n_vertices"], "seed": opts["seed"],
                 **{k: opts.get(k, v) for k, v in SESSION_DEFAULTS.items()},
                 "plan": row.initial_plan,
                 "events": [_state_event(e.kind, e.payload) for e in events]}
        return self.sessions.restore(ctx, state)

    @contextmanager
    def _untouched_unless_stored(self, live: LiveMission):
        """The session refuses bad input (InputError, OrangeError) before it changes; after
        any other failure its state is unknown, so it is dropped and rebuilt from the store
        on the next request."""
        try:
            yield
        except OrangeError:
            raise
        except Exception:
            with self._guard:
                self._live.pop(live.row.id, None)
            raise

    def _commit(self, live: LiveMission, events: list, decision) -> dict:
        try:
            self.store.add_events(live.row.id, events)
        except Exception:
            with self._guard:  # the session is ahead of the store: rebuild it next time
                self._live.pop(live.row.id, None)
            raise
        self._count(live, events)
        live.last_batch = None
        live.last_decision = decision_dict(decision)
        return live.last_decision

    @staticmethod
    def _count(live: LiveMission, events: list) -> None:
        live.events += len(events)
        live.plan_version += sum(kind == "plan" for kind, _ in events)
        live.updated_s = time.time()

    def _rebuild(self, row: MissionRow) -> LiveMission:
        t0 = time.perf_counter()
        try:
            events = self.store.events(row.id)
            session = self._restored(row, events)
            live = LiveMission(row, session)
            for e in events:
                if e.kind == "telemetry":
                    live.samples += len(e.payload["samples"])
                    live.batches += 1
                elif e.kind == "map":
                    live.map_updates += [("obstacle", g) for g in e.payload["obstacles"]]
                    live.map_updates += [("no_go", g) for g in e.payload["no_go"]]
                    live.map_version += 1
            self._count(live, [(e.kind, None) for e in events])
            live.last_decision = decision_dict(session.decision())
            if events and events[-1].kind == "telemetry":
                live.last_batch = events[-1].payload["samples"]
        except Exception as exc:
            log.exception("replaying mission %s failed", row.id)
            raise MissionUnavailable(
                f"mission {row.id!r} could not be rebuilt from the database: "
                f"{type(exc).__name__}: {exc}") from None
        log.info("mission %s rebuilt: %d events in %.1f s", row.id, len(events),
                 time.perf_counter() - t0)
        return live


def settle_heap() -> None:
    """Collect, then freeze what is left (``gc.freeze``): a mission's roadmap, fields and
    plan (hundreds of thousands of objects) live as long as the mission, and every full
    collection would walk them again, in the middle of a telemetry request. Measured: 131 ms
    per full collection with 5 missions in one process (``gc.callbacks``); with 20 missions
    ``bench service`` had 0.3-0.75 s stalls that made its whole p99, gone once frozen. Frozen
    objects are still freed when no longer referenced; only reference cycles among them wait
    for the next ``settle_heap`` (which unfreezes first). At exit everything is unfrozen
    again: the interpreter's last collection skips frozen objects, so OMPL's bindings would
    find their objects still alive and print nanobind's "leaked" report."""
    gc.unfreeze()
    gc.collect()
    gc.freeze()
    atexit.unregister(gc.unfreeze)  # registered once however often the heap is settled
    atexit.register(gc.unfreeze)


def _source(row: MissionRow) -> ScenarioSource:
    return ScenarioSource(row.scenario_name, row.scenario_toml, row.inline)


def _state_event(kind: str, payload: dict) -> dict:
    """A stored event in ``MissionSession.state_dict`` form."""
    if kind == "telemetry":
        return {"feed": payload["samples"]}
    if kind == "map":
        return {"map": payload}
    return {"plan": payload}


# --- views -------------------------------------------------------------------------------
def decision_dict(decision) -> dict:
    return decision.to_dict() if hasattr(decision, "to_dict") else dict(decision)


def count_vertices(geometries) -> int:
    """Vertices in GeoJSON geometries (malformed ones count 0: the session refuses them)."""
    total = 0
    for g in geometries:
        with suppress(Exception):
            total += len(shapely.get_coordinates(shape(g)))
    return total


def map_geojson(live: LiveMission) -> dict:
    """The mission's map (boundary, obstacles, no-go, surfaces, home) plus its updates."""
    m = live.ctx.world.true_map  # the session's map: the scenario's plus the updates, in order
    n_obstacles = sum(kind == "obstacle" for kind, _ in live.map_updates)
    n_no_go = len(live.map_updates) - n_obstacles
    feats = [_feature("boundary", m.boundary)]
    feats += [_feature("surface", s.polygon, name=s.name, crr=s.crr) for s in m.surfaces]
    for kind, geoms, n_new in (("obstacle", m.obstacles, n_obstacles),
                               ("no_go", m.no_go, n_no_go)):
        first_new = len(geoms) - n_new
        feats += [_feature(kind, g, **({"update": True} if i >= first_new else {}))
                  for i, g in enumerate(geoms)]
    feats.append(_feature("home", shapely.Point(live.ctx.world.home_xy_m)))
    top = {}
    if m.default_surface is not None:
        top["default_surface"] = {"name": m.default_surface[0], "crr": m.default_surface[1]}
    return {"type": "FeatureCollection", **top, "features": feats}


def live_view(live: LiveMission) -> dict:
    """What the operator page polls: position, trail, covered area, decision, versions."""
    s = live.session
    trail = np.asarray(getattr(s, "trail_xy_m", np.empty((0, 2))), float).reshape(-1, 2)
    if len(trail) > MAX_TRAIL_POINTS:
        idx = np.unique(np.r_[np.linspace(0, len(trail) - 1, MAX_TRAIL_POINTS).astype(int),
                              len(trail) - 1])
        trail = trail[idx]
    covered = getattr(s, "covered", None)
    position = getattr(s, "position_xy_m", None)
    return {
        "mission_id": live.row.id,
        "scenario": live.row.scenario_name,
        "samples": live.samples,
        "batches": live.batches,
        "events": live.events,
        "plan_version": live.plan_version,
        "map_version": live.map_version,
        "updated_s": live.updated_s,
        "position_xy_m": None if position is None else [float(v) for v in position],
        "energy_used_J": float(getattr(s, "energy_used_J", 0.0)),
        "time_s": float(getattr(s, "time_s", 0.0)),
        "trail_xy_m": np.round(trail, 3).tolist(),
        "covered": None if covered is None or covered.is_empty
        else mapping(covered.simplify(0.02)),
        "decision": live.last_decision,
    }


def status(live: LiveMission) -> dict:
    """A mission's summary: scenario, options, counters, decision, plan summary."""
    summary = dict(getattr(live.session.plan, "summary", {}) or {})
    return {
        "mission_id": live.row.id,
        "scenario": live.row.scenario_name,
        "inline_scenario": live.row.inline,
        "created_s": live.row.created_s,
        "n_vertices": live.row.options["n_vertices"],
        "seed": live.row.options["seed"],
        "samples": live.samples,
        "batches": live.batches,
        "map_updates": live.map_version,
        "plan_version": live.plan_version,
        "decision": live.last_decision,
        "plan_summary": summary,
    }


def _feature(kind: str, geom, **props) -> dict:
    return {"type": "Feature", "properties": {"kind": kind, **props}, "geometry": mapping(geom)}
