"""Nothing acknowledged is lost: ``orange-plan serve`` killed with SIGKILL under load.

The real server (``python -m orange_plan.cli serve --port P --db TMP`` in a subprocess), two
missions on ``rusti_v1_box`` (300-vertex roadmaps), one thread per mission posting telemetry
batches back to back. The server is killed (SIGKILL: no shutdown, no flush) while they post,
then started again on the same database. Every batch answered 2xx before the kill must be
there after the restart: sample count, last position, energy used and time all equal the
state the last acknowledged batch answered, or (the batch in flight when the server died may
have been committed without its answer getting out) the state after that one batch more.
"""

from __future__ import annotations

import math
import threading
import time

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")
pytest.importorskip("uvicorn")
import httpx

from orange_plan.bench.service_load import Robot, ServerProcess, tour_path

BATCH = 20


class Poster(threading.Thread):
    """Posts batches to one mission until stopped or the server goes away; remembers every
    batch sent and which were acknowledged (2xx)."""

    def __init__(self, url: str, headers: dict, robot: Robot):
        super().__init__(daemon=True)
        self.url, self.headers, self.robot = url, headers, robot
        self.acked: list[tuple[list, dict]] = []  # (samples, answered decision)
        self.in_flight: list | None = None
        self.refused: list = []
        self.stop = threading.Event()

    def run(self) -> None:
        with httpx.Client(headers=self.headers, timeout=10.0) as c:
            while not self.stop.is_set():
                samples = self.robot.batch(BATCH)
                self.in_flight = samples
                try:
                    r = c.post(f"{self.url}/missions/{self.robot.mission_id}/telemetry",
                               json={"samples": samples})
                except httpx.HTTPError:
                    return  # the server died: this batch may or may not be stored
                if 200 <= r.status_code < 300:
                    self.acked.append((samples, r.json()))
                    self.in_flight = None
                else:
                    self.refused.append((r.status_code, r.text))
                    return


def check_state(after: dict, live: dict, poster: Poster) -> None:
    """The restarted mission holds every acknowledged batch (and at most the one in flight)."""
    acked = poster.acked
    n_acked = sum(len(s) for s, _ in acked)
    candidates = [(n_acked, acked[-1][0][-1], acked[-1][1])]
    if poster.in_flight is not None:  # may have been committed before the kill
        candidates.append((n_acked + len(poster.in_flight), poster.in_flight[-1], None))
    n = after["samples"]
    match = [c for c in candidates if c[0] == n]
    assert match, (f"{n} samples after the restart; acknowledged {n_acked}"
                   + (f" (+{len(poster.in_flight)} in flight)" if poster.in_flight else ""))
    _, last, decision = match[0]
    assert live["position_xy_m"] == pytest.approx([last["x_m"], last["y_m"]], abs=1e-9)
    assert live["time_s"] == pytest.approx(last["t_s"], abs=1e-9)
    if decision is not None:  # the state the client was told: the same energy, the same time
        assert live["energy_used_J"] == pytest.approx(decision["energy_used_J"], rel=1e-9)
        assert after["decision"]["energy_used_J"] == pytest.approx(
            decision["energy_used_J"], rel=1e-9)
    else:  # one more batch than acknowledged: more energy than the last answer said
        assert live["energy_used_J"] > acked[-1][1]["energy_used_J"]


def test_sigkill_under_load_loses_no_acknowledged_batch(tmp_path):
    db = tmp_path / "missions.sqlite"
    server = ServerProcess(db, token="restart-test").start()
    try:
        robots = []
        with httpx.Client(headers=server.headers, timeout=60.0) as c:
            for seed in range(2):
                r = c.post(f"{server.url}/missions",
                           json={"scenario": "rusti_v1_box", "n_vertices": 300, "seed": seed})
                assert r.status_code == 201, r.text
                mid = r.json()["mission_id"]
                plan = c.get(f"{server.url}/missions/{mid}/plan").json()
                robots.append(Robot(mid, tour_path(plan, 0.3, 10.0), seed=seed))
        posters = [Poster(server.url, server.headers, r) for r in robots]
        for p in posters:
            p.start()
        deadline = time.monotonic() + 20.0
        while min(len(p.acked) for p in posters) < 15 and time.monotonic() < deadline:
            time.sleep(0.02)
        server.kill()  # mid-load: both threads are posting
        for p in posters:
            p.join(timeout=15)
            assert not p.is_alive()
            assert not p.refused, p.refused
            assert len(p.acked) >= 15
    finally:
        server.kill()

    server = ServerProcess(db, token="restart-test", log=tmp_path / "second.log").start()
    try:
        with httpx.Client(headers=server.headers, timeout=60.0) as c:
            listed = c.get(f"{server.url}/missions").json()["missions"]
            assert {m["mission_id"] for m in listed} == {p.robot.mission_id for p in posters}
            for p in posters:
                mid = p.robot.mission_id
                after = c.get(f"{server.url}/missions/{mid}").json()
                live = c.get(f"{server.url}/missions/{mid}/live").json()
                check_state(after, live, p)
                assert after["batches"] in (len(p.acked), len(p.acked) + 1)
                assert math.isfinite(after["decision"]["homing_margin_J"])
                # the robot goes on from the last stored sample: the service takes it
                if after["samples"] > sum(len(s) for s, _ in p.acked):
                    p.in_flight = None  # it was stored: go on after it
                else:
                    p.robot.rewind(len(p.in_flight or []))
                nxt = p.robot.batch(BATCH)
                r = c.post(f"{server.url}/missions/{mid}/telemetry", json={"samples": nxt})
                assert r.status_code == 200, r.text
                assert c.get(f"{server.url}/missions/{mid}").json()["samples"] == \
                    after["samples"] + BATCH
    finally:
        server.stop()
