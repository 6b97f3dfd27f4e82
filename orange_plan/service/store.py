"""The service's SQLite store: missions and their acknowledged events.

One row per mission (its scenario TOML text, session options and first plan) and one row per
acknowledged change, in order: a ``telemetry`` batch (the samples as posted), a ``map``
update (the posted geometries), a ``plan`` adopted by a replan (its plan GeoJSON (docs/formats.md)). A request
is acknowledged only after its transaction has committed, so a restart loses nothing that a
client was told succeeded. The database runs in WAL mode with ``synchronous=FULL``.

Restart = replay: a mission's session is rebuilt with ``MissionSession.from_state`` from the
stored scenario, first plan and events in ``seq`` order (batches fed again, map updates
applied, stored plans adopted: nothing is planned again, so the rebuilt session is the one
that answered).
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from orange_plan.errors import InputError

SCHEMA_VERSION = 1

SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS missions (
    id TEXT PRIMARY KEY,
    created_s REAL NOT NULL,
    scenario_name TEXT NOT NULL,
    scenario_toml TEXT NOT NULL,
    inline INTEGER NOT NULL,
    options TEXT NOT NULL,
    initial_plan TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS events (
    mission_id TEXT NOT NULL REFERENCES missions(id) ON DELETE CASCADE,
    seq INTEGER NOT NULL,
    kind TEXT NOT NULL CHECK (kind IN ('telemetry', 'map', 'plan')),
    payload TEXT NOT NULL,
    created_s REAL NOT NULL,
    PRIMARY KEY (mission_id, seq)
);
"""


@dataclass(frozen=True)
class MissionRow:
    """A stored mission."""

    id: str
    created_s: float
    scenario_name: str
    scenario_toml: str
    inline: bool
    options: dict
    initial_plan: dict


@dataclass(frozen=True)
class EventRow:
    """A stored, acknowledged change to a mission."""

    seq: int
    kind: str
    payload: dict
    created_s: float


class Store:
    """Missions and events in one SQLite file (``":memory:"`` for a throw-away store).

    One connection shared by the worker threads under a lock; every write is one
    transaction, committed before the method returns.
    """

    def __init__(self, path: str | Path):
        self.path = str(path)
        if self.path != ":memory:":
            Path(self.path).parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.RLock()
        try:
            self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._db.executescript(SCHEMA)
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"{self.path}: cannot open the mission database ({exc})") from None
        with self.transaction() as db:
            row = db.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
            if row is None:
                db.execute("INSERT INTO meta VALUES ('schema', ?)", (str(SCHEMA_VERSION),))
            elif int(row[0]) != SCHEMA_VERSION:
                raise StoreError(f"{self.path}: database schema {row[0]}, this version reads "
                                 f"{SCHEMA_VERSION}")

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """BEGIN IMMEDIATE ... COMMIT (ROLLBACK on any exception)."""
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                yield self._db
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
            self._db.execute("COMMIT")

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # --- missions ------------------------------------------------------------------------
    def add_mission(self, row: MissionRow) -> None:
        with self.transaction() as db:
            db.execute("INSERT INTO missions VALUES (?, ?, ?, ?, ?, ?, ?)",
                       (row.id, row.created_s, row.scenario_name, row.scenario_toml,
                        int(row.inline), json.dumps(row.options), json.dumps(row.initial_plan)))

    def mission(self, mission_id: str) -> MissionRow | None:
        with self._lock:
            r = self._db.execute("SELECT * FROM missions WHERE id=?", (mission_id,)).fetchone()
        return None if r is None else MissionRow(r[0], r[1], r[2], r[3], bool(r[4]),
                                                 json.loads(r[5]), json.loads(r[6]))

    def mission_ids(self) -> list[str]:
        with self._lock:
            rows = self._db.execute("SELECT id FROM missions ORDER BY created_s, id").fetchall()
        return [r[0] for r in rows]

    def delete_mission(self, mission_id: str) -> bool:
        with self.transaction() as db:
            db.execute("DELETE FROM events WHERE mission_id=?", (mission_id,))
            return db.execute("DELETE FROM missions WHERE id=?", (mission_id,)).rowcount > 0

    # --- events --------------------------------------------------------------------------
    def add_events(self, mission_id: str, events: list[tuple[str, dict]]) -> int:
        """Append ``(kind, payload)`` events in one transaction; the last sequence number."""
        texts = [(kind, json.dumps(payload)) for kind, payload in events]
        with self.transaction() as db:
            (seq,) = db.execute("SELECT COALESCE(MAX(seq), 0) FROM events WHERE mission_id=?",
                                (mission_id,)).fetchone()
            for kind, text in texts:
                seq += 1
                db.execute("INSERT INTO events VALUES (?, ?, ?, ?, ?)",
                           (mission_id, seq, kind, text, time.time()))
        return seq

    def events(self, mission_id: str) -> list[EventRow]:
        with self._lock:
            rows = self._db.execute(
                "SELECT seq, kind, payload, created_s FROM events WHERE mission_id=? "
                "ORDER BY seq", (mission_id,)).fetchall()
        return [EventRow(r[0], r[1], json.loads(r[2]), r[3]) for r in rows]


class StoreError(InputError):
    """The database file cannot be opened or has another schema."""
