"""Random routes of the concealed-effect cases: turns, walks, hills or a surface, drawn on
the map as given (``sim.concealed``)."""

from __future__ import annotations

import math

import numpy as np

from orange_plan.errors import InputError, OrangeError
from orange_plan.sim.route import Route

STYLES = {
    # step length range [m], heading change range [deg], share of waypoints from the pool
    "mixed": ((15.0, 60.0), (10.0, 120.0), 0.5),
    "walks": ((10.0, 40.0), (10.0, 120.0), 0.85),
    "turns": ((4.0, 12.0), (45.0, 150.0), 0.0),
    "hills": ((20.0, 60.0), (10.0, 90.0), 0.6),
    # half the waypoints on the surface: a surface's rolling is its contrast with the
    # others, and a route nearly all on one surface (91-98 % with 0.85) shows only the
    # default coefficient, mis-set (a surface route that must also vary its load,
    # "surface:<name>+hills", takes the other half from the hills)
    "surface": ((10.0, 40.0), (10.0, 120.0), 0.5),
    "aerial": ((30.0, 120.0), (10.0, 150.0), 0.0),
}


MAX_ROUTE_TRIES = 200_000
"""Candidate draws before a route search gives up (a 30-min run needs a few hundred)."""


def _style_surface(style: str) -> str | None:
    """The surface a ``"surface:<name>[+hills]"`` route style is about (None for the others)."""
    if not style.startswith("surface:"):
        return None
    return style.removeprefix("surface:").removesuffix("+hills")


def _pool_ok(world, style: str, surface: str | None):
    """Predicate on candidate points (x, y) arrays for the style's pool."""
    if style == "hills":
        xs = np.linspace(*world.map.boundary.bounds[0::2], 41)
        ys = np.linspace(*world.map.boundary.bounds[1::2], 41)
        gx, gy = np.meshgrid(xs, ys)
        top = float(np.max(world.elevation_at(gx, gy)))
        return lambda x, y: world.elevation_at(x, y) >= 0.3 * top
    if surface is not None:
        code = world.map.surface_names.index(surface)
        return lambda x, y: world.surface_code_at(x, y) == code
    return lambda x, y: world.surface_code_at(x, y) >= 0  # "mixed", "walks": walks, plazas


def _route(rng, world, style: str, length_m: float, v_range_mps: tuple[float, float]) -> Route:
    """A random collision-free route of at least ``length_m`` (see ``STYLES``; a
    ``"surface:<name>+hills"`` route takes its non-surface waypoints from the hills)."""
    surface, plus_hills = _style_surface(style), style.endswith("+hills")
    style = style.removesuffix("+hills")
    (l_lo, l_hi), (t_lo, t_hi), p_pool = STYLES["surface" if surface else style]
    pools = [_pool_ok(world, style, surface)]
    if plus_hills:
        pools.append(_pool_ok(world, "hills", None))
    points = [_pool_points(rng, world, ok) for ok in pools] if p_pool > 0 else [np.zeros((0, 2))]
    pts = [points[0][0] if len(points[0]) else np.asarray(world.home_xy_m, float)]
    heading, total = rng.uniform(0, 2 * np.pi), 0.0
    for _ in range(MAX_ROUTE_TRIES):
        if total >= length_m:
            break
        here = pts[-1]
        # pool 0 (the style's) with p_pool, else the hills pool if any, else a free step
        which = 0 if rng.random() < p_pool else (1 if plus_hills else None)
        from_pool = which is not None
        if from_pool:  # a pool point whose straight segment stays mostly on the pool
            on_pool, pool = pools[which], points[which]
            cand = pool[rng.integers(len(pool), size=64)]
            dist = np.hypot(*(cand - here).T)
            keep = dist > l_lo
            if on_pool(here[:1], here[1:])[0]:
                keep &= dist < 6 * l_hi
                cand = cand[keep][_mostly_on(on_pool, here, cand[keep])]
            else:  # off the pool: back onto it by the nearest way
                cand = cand[keep][np.argsort(dist[keep])]
        else:
            n = 32
            turn = np.deg2rad(rng.uniform(t_lo, t_hi, n)) * rng.choice([-1.0, 1.0], n)
            step = rng.uniform(l_lo, l_hi, n)
            cand = here + np.c_[np.cos(heading + turn), np.sin(heading + turn)] * step[:, None]
        cand = cand[world.is_free(cand[:, 0], cand[:, 1])]
        cand = cand[world.segments_free(np.broadcast_to(here, cand.shape), cand)] if len(cand) else cand
        if not len(cand):
            if not from_pool:
                heading += np.pi  # boxed in: turn round
            continue
        nxt = cand[0]
        heading = math.atan2(nxt[1] - here[1], nxt[0] - here[0])
        total += float(np.hypot(*(nxt - here)))
        pts.append(nxt)
    else:
        raise OrangeError(f"no {style} route of {length_m:.0f} m found in "
                          f"{MAX_ROUTE_TRIES} tries (reached {total:.0f} m)")
    xy = np.asarray(pts)
    return Route(xy, rng.uniform(*v_range_mps, len(xy)), f"concealed route ({style})")


def _pool_points(rng, world, on_pool, n: int = 40_000) -> np.ndarray:
    """Free points of the pool, uniformly drawn (a small plaza still gets a few hundred)."""
    x0, y0, x1, y1 = world.map.boundary.bounds
    cand = np.c_[rng.uniform(x0, x1, n), rng.uniform(y0, y1, n)]
    ok = on_pool(cand[:, 0], cand[:, 1]) & world.is_free(cand[:, 0], cand[:, 1])
    if not ok.any():
        raise InputError("the map has no free point for the route's pool (surface or hills)")
    return cand[ok]


def _mostly_on(on_pool, start, ends, share: float = 0.8) -> np.ndarray:
    """True for segments start -> end with at least ``share`` of 16 points on the pool."""
    if not len(ends):
        return np.zeros(0, bool)
    f = np.linspace(0.0, 1.0, 16)
    x = start[0] + (ends[:, 0:1] - start[0]) * f
    y = start[1] + (ends[:, 1:2] - start[1]) * f
    return np.mean(on_pool(x, y), axis=1) >= share
