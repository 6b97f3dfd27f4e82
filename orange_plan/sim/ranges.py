"""Range estimates judged against simulated runs to depletion: the route, the offline
estimate on it and the accuracy measure that ``bench online`` and ``report paper`` share.

* route (``lap_route``): the a priori probe of the generalised range (out-and-back rays from
  home in ``N_RAYS`` headings, ``physics.range.radial_probe_paths``), rays cut so one lap is
  at most ``LAP_FRACTION`` of the offline range, at the scenario's v_opt; a run repeats it
  until the truth's usable energy is spent, and ``d_true`` is the distance covered then.
* offline (``offline_range_m``): Eq. 11 with the path integral taken a priori on that very
  route with the scenario's model: ``d = E_avail / (E_route / L_route)``.
* accuracy (``accuracy_pct``): ``100 (1 - |d_pred - d_true| / d_true)``, the paper's measure.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from orange_plan.physics.pathcost import path_energy
from orange_plan.physics.range import radial_probe_paths
from orange_plan.sim.route import Route

if TYPE_CHECKING:
    from orange_plan.context import Context

N_RAYS = 8
"""Headings of the probe route's out-and-back rays."""
LAP_FRACTION = 0.1
"""Probe rays are cut so that one lap is at most this fraction of the offline range."""
PREDICT_AT = (0.2, 0.4, 0.6, 0.8)
"""Fractions of the run (mission time) at which the online estimate is taken."""


def accuracy_pct(d_pred: float, d_true: float) -> float:
    """Range accuracy ``100 (1 - |d_pred - d_true| / d_true)`` [%] (the paper's measure)."""
    return 100.0 * (1.0 - abs(d_pred - d_true) / d_true)


def probe_route(ctx: Context, n_rays: int = N_RAYS, max_ray_m: float | None = None) -> Route:
    """The a priori route: out-and-back rays from home joined into one closed polyline, each
    ray cut at ``max_ray_m`` from home (no speeds: NaN)."""
    rays = radial_probe_paths(ctx.world, n_rays)
    if max_ray_m is not None:
        for r in rays:
            out = r[1] - r[0]
            length = float(np.hypot(*out))
            if length > max_ray_m:
                r[1] = r[0] + out * (max_ray_m / length)
    xy = np.vstack([rays[0][:1]] + [r[1:] for r in rays])
    return Route(xy, np.full(len(xy), np.nan), "probe rays")


def offline_range_m(ctx: Context, route: Route) -> float:
    """Generalised offline range (Eq. 11) with the path integral taken on ``route`` [m]."""
    speed = route.speed_mps[:-1]
    e = path_energy(ctx.model, ctx.world, route.xy_m, speed, ctx.conditions)
    length = float(np.sum(np.hypot(*np.diff(route.xy_m, axis=0).T)))
    return ctx.scenario.battery.usable_J / (e.total_J / length)


def lap_route(ctx: Context) -> Route:
    """The probe route at the scenario's v_opt, rays cut so a lap is <= ``LAP_FRACTION`` of
    the offline range (a long field would otherwise never complete one lap)."""
    speed = ctx.cruise_speed_mps
    full = probe_route(ctx).with_default_speed(speed)
    cap = LAP_FRACTION * offline_range_m(ctx, full) / (2 * N_RAYS)
    return probe_route(ctx, max_ray_m=cap).with_default_speed(speed)
