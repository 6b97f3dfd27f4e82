"""``bench watch``: do decisions follow telemetry within ``TARGET_S`` at 10 Hz?

A simulated vehicle (``service.fake_vehicle``, in a thread, real time) flies a lawnmower over
the drone field and streams MAVLink on 127.0.0.1; a watch (``service.watch``) in the same
process reads it and decides. A decision's lag is the wall time from when the vehicle sent
the newest sample it covers (its time since boot on the vehicle's clock) to when the
decision is made: the socket's queue, the reading, the batch and the session's decision. A
vehicle that runs late only adds to it, so the figure is an upper bound.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

TARGET_S = 0.2
"""Longest lag of a decision behind the telemetry it covers [s]."""
RATE_HZ = 10.0
"""Telemetry rate of the benchmark [Hz]."""


def lawnmower_xy(lanes: int = 12, x0: float = 30.0, step: float = 16.0,
                 y: tuple[float, float] = (30.0, 170.0)) -> np.ndarray:
    """Lanes over the drone field west of its copse and south of its tree line, from home
    (30, 30) and back [m]."""
    rows, up = [], True
    for i in range(lanes):
        ys = y if up else y[::-1]
        rows += [(x0 + step * i, v) for v in ys]
        up = not up
    return np.array([*rows, (x0, y[0])], float)


def run_watch_bench(ctx, duration_s: float = 60.0, rate_Hz: float = RATE_HZ,
                    speedup: float = 1.0, vertices: int = 1000) -> dict:
    """Fly for ``duration_s`` wall seconds with a watch on loopback; the lags (docs/json.md,
    bench watch)."""
    from orange_plan.planning.session import MissionSession
    from orange_plan.service.fake_vehicle import BOOT_S, FakeVehicle, VehicleOptions
    from orange_plan.service.mavlink_link import open_link
    from orange_plan.service.watch import Watch, WatchOptions, route_plan, run_watch

    xy = lawnmower_xy()
    speed = np.full(len(xy), ctx.cruise_speed_mps)
    session = MissionSession(ctx, route_plan(xy, speed), n_vertices=vertices, closed_loop=True)
    session.decision()  # the way-home roadmap, before the clock starts
    port = _free_udp_port()
    watch_link = open_link(f"udpin:127.0.0.1:{port}", 255, 191)
    vehicle_link = open_link(f"udpout:127.0.0.1:{port}", 1, 1)
    vehicle = FakeVehicle(ctx, xy, speed, None, vehicle_link,
                          VehicleOptions(speedup=speedup, rate_Hz=rate_Hz, takeoff_after_s=0.0,
                                         linger_s=0.0), say=lambda line: None)
    watch = Watch(session, ctx.world.map.origin, watch_link, WatchOptions(),
                  say=lambda line: None)
    flying = threading.Thread(target=_fly_for, args=(vehicle, duration_s), daemon=True)
    try:
        flying.start()
        run_watch(watch_link, watch, stop_after_s=duration_s)
    finally:
        flying.join(timeout=5.0)
        watch_link.close()
        vehicle_link.close()
    sent = [vehicle._wall0 + (boot - BOOT_S) / speedup for boot, _ in watch.followed]
    lags = np.array([done - s for s, (_, done) in zip(sent, watch.followed)], float)
    return _summary(lags, watch, rate_Hz, speedup, duration_s)


def _free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _fly_for(vehicle, duration_s: float) -> None:
    """Fly until the flight ends or the benchmark's time is up."""
    import contextlib

    end = time.monotonic() + duration_s
    with contextlib.suppress(OSError):  # the link closed at the end
        vehicle.run(stop_when=lambda: time.monotonic() >= end)


def _summary(lags: np.ndarray, watch, rate_Hz: float, speedup: float, duration_s: float) -> dict:
    def pct(q):
        return float(np.percentile(lags, q)) if lags.size else math.nan

    return {"rate_Hz": rate_Hz, "speedup": speedup, "duration_s": duration_s,
            "decisions": int(lags.size), "lag_median_s": pct(50), "lag_p95_s": pct(95),
            "lag_max_s": float(lags.max()) if lags.size else math.nan,
            "within_target": float(np.mean(lags <= TARGET_S)) if lags.size else math.nan,
            "target_s": TARGET_S, "meets_target": bool(lags.size and pct(95) <= TARGET_S),
            "samples_dropped": watch.reader.dropped}
