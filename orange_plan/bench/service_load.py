"""Load benchmark of the HTTP service (``orange-plan bench service``; targets).

One real server: ``python -m orange_plan.cli serve`` in a subprocess on 127.0.0.1, a free
port, a temporary database (WAL, ``synchronous=FULL``: every answered batch is committed),
a bearer token. ``robots`` missions on a small scenario (``rusti_v1_box``, a
``n_vertices`` roadmap) are created first; then each robot posts telemetry batches of
``batch`` samples (10 Hz robot time: ``t_s`` goes on 0.1 s a sample, the robot follows its
mission's planned tour at the plan's pace) to ``POST /missions/{id}/telemetry``.

The load is paced: the robots together offer ``rate`` samples/s (each robot posts one batch
every ``robots * batch / rate`` s, staggered), as a fleet of robots would. A robot waits for
the answer to its batch before sending the next one (its samples must arrive in time order);
when an answer comes late the next batch goes at once, so a server that cannot keep up shows
a lower achieved rate, not a hidden queue. A batch counts when it was due and sent within the
window (its answer may come after the window; nothing is sent after it), so a server that
keeps up answers exactly the offered rate. Latency is per request, from just before the
request is written to the end of the answer (httpx.AsyncClient, one event loop, one
keep-alive connection per robot). Every robot's first batch is sent before the paced load
(it builds the mission's to-home field: a start-up cost, reported on its own), and the first
``warmup_s`` of the paced load are not counted.

Measured per repeat: samples/s and requests/s answered 2xx within the window, latency
p50/p95/p99, errors (non-2xx or transport); reported: medians over the repeats, with the
machine's load average (``os.getloadavg``) before and after, since the numbers depend on
what else runs.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import secrets
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from orange_plan.errors import OrangeError
from orange_plan.planning.plan import read_tour

TARGETS = {"samples_per_s": 2000.0, "p99_ms": 50.0}
SCENARIO = "rusti_v1_box"


@dataclass
class RepeatResult:
    """One timed window of load."""

    seconds: float
    samples: int
    requests: int
    errors: int
    samples_per_s: float
    requests_per_s: float
    p50_ms: float
    p95_ms: float
    p99_ms: float
    max_ms: float
    first_batch_ms: float


@dataclass
class ServiceBenchResult:
    """Medians over the repeats (``repeats`` has each one)."""

    scenario: str
    n_vertices: int
    robots: int
    batch: int
    offered_samples_per_s: float
    seconds: float
    samples_per_s: float
    requests_per_s: float
    p50_ms: float
    p95_ms: float
    p99_ms: float
    first_batch_ms: float
    errors: int
    load_before: list
    load_after: list
    cpus: int
    repeats: list = field(default_factory=list)

    def ratios(self) -> dict:
        """<= 1 when the target is met."""
        return {"samples_per_s": TARGETS["samples_per_s"] / max(self.samples_per_s, 1e-9),
                "p99_ms": self.p99_ms / TARGETS["p99_ms"]}

    def to_dict(self) -> dict:
        d = asdict(self)
        d["targets"] = dict(TARGETS)
        d["ratios"] = self.ratios()
        d["target_met"] = all(v <= 1.0 for v in d["ratios"].values())
        return d


# --- the server ------------------------------------------------------------------------------
class ServerFailed(OrangeError):
    """The server subprocess did not start."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ServerProcess:
    """``orange-plan serve`` in a subprocess (``python -m orange_plan.cli serve``)."""

    def __init__(self, db: Path, *, token: str | None = None, port: int | None = None,
                 log: Path | None = None):
        self.db, self.token = Path(db), token
        self.port = port or free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = log or self.db.with_suffix(".log")
        self.proc: subprocess.Popen | None = None

    def start(self, timeout_s: float = 60.0) -> ServerProcess:
        import httpx

        env = dict(os.environ)
        env.pop("ORANGE_PLAN_TOKEN", None)
        if self.token is not None:
            env["ORANGE_PLAN_TOKEN"] = self.token
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "orange_plan.cli", "serve", "--host", "127.0.0.1",
                 "--port", str(self.port), "--db", str(self.db)],
                stdout=log, stderr=subprocess.STDOUT, env=env)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise ServerFailed(f"the server exited ({self.proc.returncode}): "
                                   f"{self.log.read_text(errors='replace')[-2000:]}")
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(f"{self.url}/health", timeout=1.0).status_code == 200:
                    return self
            time.sleep(0.05)
        self.stop()
        raise ServerFailed(f"the server did not answer /health within {timeout_s:g} s")

    @property
    def headers(self) -> dict:
        return {} if self.token is None else {"Authorization": f"Bearer {self.token}"}

    def kill(self) -> None:
        """SIGKILL: no shutdown, no flush (a crash)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=30)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.kill()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


# --- the robots ------------------------------------------------------------------------------
def tour_path(plan_geojson: dict, speed_mps: float, rate_Hz: float) -> np.ndarray:
    """Positions every 1/rate_Hz s along the plan's tour at ``speed_mps`` (a closed walk:
    out along the tour and back, so the robot never jumps)."""
    xy, _ = read_tour(plan_geojson)
    xy = np.vstack([xy, xy[::-1][1:]])
    seg = np.hypot(*np.diff(xy, axis=0).T)
    s = np.r_[0.0, np.cumsum(seg)]
    if s[-1] <= 0:
        return xy[:1]
    at = np.arange(0.0, s[-1], speed_mps / rate_Hz)
    return np.column_stack([np.interp(at, s, xy[:, 0]), np.interp(at, s, xy[:, 1])])


class Robot:
    """A mission's telemetry source: batches of samples at 10 Hz robot time."""

    def __init__(self, mission_id: str, path: np.ndarray, seed: int, rate_Hz: float = 10.0):
        self.mission_id, self.path, self.rate_Hz = mission_id, path, rate_Hz
        self.rng = np.random.default_rng(seed)
        self.i = 0
        self.sent = 0  # samples acknowledged

    def batch(self, n: int) -> list[dict]:
        rows = []
        for _ in range(n):
            self.i += 1
            x, y = self.path[self.i % len(self.path)]
            rows.append({"t_s": round(self.i / self.rate_Hz, 3),
                         "power_W": round(float(9.0 + self.rng.normal(0.0, 0.3)), 3),
                         "x_m": round(float(x), 4), "y_m": round(float(y), 4),
                         "v_mps": 0.3})
        return rows

    def rewind(self, n: int) -> None:
        """A refused or lost batch: send those samples again (same time stamps)."""
        self.i -= n


async def _robot_loop(client, url: str, robot: Robot, batch: int, period_s: float,
                      offset_s: float, t_start: float, t_count: float, t_end: float,
                      latencies: list, counts: dict) -> None:
    import httpx

    k = 0
    while True:
        due = t_start + offset_s + k * period_s
        now = time.perf_counter()
        if due >= t_end:
            return
        if due > now:
            await asyncio.sleep(due - now)
        k += 1
        body = {"samples": robot.batch(batch)}
        t0 = time.perf_counter()
        if t0 >= t_end:  # behind schedule at the end: what was not sent is not counted
            robot.rewind(batch)
            return
        try:
            r = await client.post(f"{url}/missions/{robot.mission_id}/telemetry", json=body)
            ok = 200 <= r.status_code < 300
        except httpx.HTTPError:
            ok = False
        t1 = time.perf_counter()
        if not ok:
            robot.rewind(batch)
        if t_count <= due:  # due and sent within the window (answered whenever it is)
            if ok:
                latencies.append(t1 - t0)
                counts["samples"] += batch
                counts["requests"] += 1
            else:
                counts["errors"] += 1


async def _first_batch(client, url: str, robot: Robot, batch: int) -> float:
    t0 = time.perf_counter()
    r = await client.post(f"{url}/missions/{robot.mission_id}/telemetry",
                          json={"samples": robot.batch(batch)})
    r.raise_for_status()
    return time.perf_counter() - t0


async def _load(url: str, headers: dict, robots: list[Robot], batch: int, rate: float,
                seconds: float, warmup_s: float) -> RepeatResult:
    import httpx

    period = len(robots) * batch / rate
    latencies: list[float] = []
    counts = {"samples": 0, "requests": 0, "errors": 0}
    limits = httpx.Limits(max_connections=len(robots), max_keepalive_connections=len(robots))
    async with httpx.AsyncClient(headers=headers, timeout=60.0, limits=limits) as client:
        # a mission's first batch builds its to-home field (~0.2 s each): a start-up cost,
        # paid by every robot once before the paced load (else the backlog of 20 of them
        # would be measured as steady-state latency); its latency is reported on its own
        first = await asyncio.gather(*(_first_batch(client, url, r, batch) for r in robots))
        t_start = time.perf_counter() + 0.2
        t_count, t_end = t_start + warmup_s, t_start + warmup_s + seconds
        await asyncio.gather(*(
            _robot_loop(client, url, r, batch, period, period * i / len(robots), t_start,
                        t_count, t_end, latencies, counts)
            for i, r in enumerate(robots)))
    ms = np.asarray(latencies) * 1e3 if latencies else np.asarray([math.nan])
    return RepeatResult(
        first_batch_ms=float(np.median(first)) * 1e3,
        seconds=seconds, samples=counts["samples"], requests=counts["requests"],
        errors=counts["errors"], samples_per_s=counts["samples"] / seconds,
        requests_per_s=counts["requests"] / seconds,
        p50_ms=float(np.percentile(ms, 50)), p95_ms=float(np.percentile(ms, 95)),
        p99_ms=float(np.percentile(ms, 99)), max_ms=float(np.max(ms)))


def create_missions(url: str, headers: dict, n: int, n_vertices: int,
                    scenario: str = SCENARIO, rate_Hz: float = 10.0,
                    speed_mps: float = 0.3) -> list[Robot]:
    """``n`` missions (seeds 0..n-1) and their robots."""
    import httpx

    robots = []
    with httpx.Client(headers=headers, timeout=120.0) as c:
        for i in range(n):
            r = c.post(f"{url}/missions", json={"scenario": scenario,
                                                "n_vertices": n_vertices, "seed": i})
            r.raise_for_status()
            mid = r.json()["mission_id"]
            plan = c.get(f"{url}/missions/{mid}/plan").json()
            robots.append(Robot(mid, tour_path(plan, speed_mps, rate_Hz), seed=i))
    return robots


def run_service_bench(*, seconds: float = 20.0, repeats: int = 3, robots: int = 20,
                      batch: int = 50, rate: float = TARGETS["samples_per_s"],
                      n_vertices: int = 300, warmup_s: float = 3.0, step=None,
                      folder: Path | None = None) -> ServiceBenchResult:
    """Start a server, create ``robots`` missions per repeat, offer ``rate`` samples/s."""
    step = step or (lambda description: None)
    load_before = list(os.getloadavg())
    runs = []
    with tempfile.TemporaryDirectory(prefix="orange-bench-service-") as tmp:
        folder = Path(folder or tmp)
        server = ServerProcess(folder / "bench.sqlite", token=secrets.token_urlsafe(16))
        step("starting the server")
        with server:
            for k in range(repeats):
                step(f"repeat {k + 1}/{repeats}: creating {robots} missions")
                fleet = create_missions(server.url, server.headers, robots, n_vertices)
                step(f"repeat {k + 1}/{repeats}: {seconds:g} s of load at {rate:g} samples/s")
                runs.append(asyncio.run(_load(server.url, server.headers, fleet, batch, rate,
                                              seconds, warmup_s)))
    med = {key: statistics.median(getattr(r, key) for r in runs)
           for key in ("samples_per_s", "requests_per_s", "p50_ms", "p95_ms", "p99_ms",
                       "first_batch_ms")}
    return ServiceBenchResult(
        scenario=SCENARIO, n_vertices=n_vertices, robots=robots, batch=batch,
        offered_samples_per_s=rate, seconds=seconds, errors=sum(r.errors for r in runs),
        load_before=load_before, load_after=list(os.getloadavg()), cpus=os.cpu_count() or 1,
        repeats=[asdict(r) for r in runs], **med)


def service_table(r: ServiceBenchResult):
    """The benchmark table (docs/benchmarks/service.md): measured, target, ratio (<= 1: met)."""
    from rich.table import Table

    ratios = r.ratios()
    t = Table(title=f"bench service: {r.robots} robots x {r.batch} samples/batch on {r.scenario}"
                    f" ({r.n_vertices} vertices), {r.offered_samples_per_s:g} samples/s offered,"
                    f" median of {len(r.repeats)} x {r.seconds:g} s", header_style="bold")
    for col in ("measure", "measured", "target", "ratio"):
        t.add_column(col, justify="left" if col == "measure" else "right")
    t.add_row("telemetry samples/s acknowledged (2xx, committed)", f"{r.samples_per_s:,.0f}",
              f">= {TARGETS['samples_per_s']:,.0f}", f"{ratios['samples_per_s']:.2f}")
    t.add_row("requests/s", f"{r.requests_per_s:,.1f}", "", "")
    t.add_row("POST latency p50 / p95", f"{r.p50_ms:.1f} / {r.p95_ms:.1f} ms", "", "")
    t.add_row("POST latency p99", f"{r.p99_ms:.1f} ms", f"<= {TARGETS['p99_ms']:g} ms",
              f"{ratios['p99_ms']:.2f}")
    t.add_row("first batch of a mission (builds its to-home field; all robots at once, "
              "before the timed load), median", f"{r.first_batch_ms:.0f} ms", "", "")
    t.add_row("errors (all repeats)", f"{r.errors}", "0", "")
    t.add_row("load average 1/5/15 min before -> after",
              " ".join(f"{v:.2f}" for v in r.load_before) + " -> "
              + " ".join(f"{v:.2f}" for v in r.load_after), f"({r.cpus} CPUs)", "")
    return t
