"""The event log of a mission session: what happened, in order, to rebuild it.

A session is its initial plan plus, in order, each sample batch, map update and adopted
plan. ``EventLog`` keeps them (a batch as its DataFrame until the state is asked for),
``EventLog.state`` writes them as JSON, and ``replay_events`` applies stored events to a
fresh session: replans are stored, not recomputed, so a restored session is the same
whatever planner time limits did.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import shapely

from orange_plan.errors import InputError
from orange_plan.planning.plan import Plan

STATE_VERSION = 1
"""Version of the ``state_dict`` layout."""


class EventLog:
    """The events of a session since its initial plan, in order."""

    def __init__(self):
        self.events: list[dict] = []

    def __len__(self) -> int:
        return len(self.events)

    def feed(self, frame: pd.DataFrame) -> None:
        self.events.append({"feed": frame})  # as JSON records only when the state is asked

    def map_update(self, obstacles, no_go) -> None:
        self.events.append({"map": {"obstacles": [shapely.geometry.mapping(p) for p in obstacles],
                                    "no_go": [shapely.geometry.mapping(p) for p in no_go]}})

    def plan(self, geojson: dict) -> None:
        self.events.append({"plan": geojson})

    def state(self, header: dict, initial_plan: Plan) -> dict:
        """The JSON-serialisable state: ``header`` (version, scenario, options), the initial
        plan and the events."""
        return json.loads(json.dumps({
            "version": STATE_VERSION, **header, "plan": initial_plan.to_geojson(),
            "events": [{"feed": _records(e["feed"])} if "feed" in e else e
                       for e in self.events],
        }, default=_json_default))


def check_state(state, scenario_name: str) -> None:
    """Refuse a state of another version or scenario (InputError, one line)."""
    if not isinstance(state, dict) or state.get("version") != STATE_VERSION:
        raise InputError(f"session state must be a dict of version {STATE_VERSION}")
    if state.get("scenario") != scenario_name:
        raise InputError(f"session state is for scenario {state.get('scenario')!r}, "
                         f"not {scenario_name!r}")


def replay_events(session, events) -> None:
    """Apply stored events to ``session`` in order (``MissionSession``: ``feed``,
    ``update_map`` without replanning, ``adopt_stored_plan``).

    Raises
    ------
    InputError
        An event of no known kind.
    """
    for event in events:
        if "feed" in event:
            session.feed(pd.DataFrame(event["feed"]))
        elif "map" in event:
            session.update_map(event["map"]["obstacles"], event["map"]["no_go"], replan=False)
        elif "plan" in event:
            session.adopt_stored_plan(event["plan"])
        else:
            raise InputError(f"session state: unknown event {sorted(event)}")


def _records(frame: pd.DataFrame) -> dict:
    """A batch as JSON-ready columns (NaN as None)."""
    return {c: [None if isinstance(v, float) and not math.isfinite(v) else v
                for v in frame[c].tolist()] for c in frame.columns}


def _json_default(obj):
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")
