"""A route flown in the simulator and scored: what ``bench plan``, ``bench mission`` and
``orange-plan sweep`` count for every flight (coverage up to the battery's exhaustion,
stranded or home, energy left), in one place below all three.

``simulate_route`` flies one route; ``Flown`` collects the segments a mission flew (one per
route it followed) and scores them with ``Flown.outcome``; ``fly_open_loop`` does both for a
plan flown as planned.

A flight may be flown as segments (a mission that changes route): the energy drawn is summed
over them and a mission is **stranded** when that sum exceeds the truth's usable energy before
the robot is home, or when it does not end within ``HOME_TOLERANCE_M`` of home.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import shapely

from orange_plan.planning.coverage import footprint
from orange_plan.sim.route import Route
from orange_plan.sim.simulator import SimResult, simulate

if TYPE_CHECKING:
    from orange_plan.context import Context

HOME_TOLERANCE_M = 1.0
"""A flight whose last position is farther than this from home did not get home [m]."""


def flown_footprint(world, xy, radius_m: float):
    """``coverage.footprint`` of recorded positions, the polyline first simplified by 2 % of r
    (10 Hz samples are centimetres apart; the buffer's area changes by well under 1 %)."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    if len(xy) > 2:
        xy = shapely.get_coordinates(shapely.LineString(xy).simplify(0.02 * radius_m))
    return footprint(world, xy, radius_m)


@dataclass
class Flown:
    """Segments flown so far: positions and power per sample, and what happened.

    ``dt`` is the sample interval [s] and ``e_avail`` the truth's usable energy [J]; ``add``
    appends a simulated segment's frame (its first ``n`` samples), ``outcome`` scores them.
    A closed loop that turned home records what it predicted for the route home
    (``return_predicted_J``, the online model's energy of it) and the reserve it kept for it
    (``return_reserve_J``); that route is the last segment flown.
    """

    dt: float
    xy: list
    power: list
    e_avail: float
    replans: int = 0
    returned_by_rule: bool = False
    note: str = ""
    return_predicted_J: float = float("nan")
    return_reserve_J: float = float("nan")

    @property
    def energy_drawn_J(self) -> float:
        """Energy drawn by the segments so far (recorded power, as ``outcome`` counts) [J]."""
        return float(sum(np.sum(p) for p in self.power) * self.dt)

    def add(self, frame, n: int | None = None) -> None:
        n = len(frame) if n is None else n
        self.xy.append(frame[["x_m", "y_m"]].to_numpy(float)[:n])
        self.power.append(frame["power_W"].to_numpy(float)[:n])

    def outcome(self, ctx: Context) -> dict:
        """The flight's score: ``coverage_m2`` sensed until the battery ran out (or the end),
        ``energy_left_J``, ``stranded`` (out of energy, or ended farther than
        ``HOME_TOLERANCE_M`` from home), ``duration_s``, ``replans``, ``returned_early``,
        ``note``; for a closed loop that turned home also ``return_predicted_J``,
        ``return_reserve_J`` and ``return_flown_J`` (the true energy of the route home)."""
        xy = np.vstack(self.xy)
        cum = np.cumsum(np.concatenate(self.power)) * self.dt
        empty = np.flatnonzero(cum > self.e_avail)
        end = int(empty[0]) + 1 if empty.size else len(xy)
        away = float(np.hypot(*(xy[-1] - np.asarray(ctx.world.home_xy_m))))
        stranded = bool(empty.size) or away > HOME_TOLERANCE_M
        area = flown_footprint(ctx.world, xy[:end], ctx.scenario.mission.sensor_radius_m).area
        out = {"coverage_m2": float(area), "energy_left_J": float(self.e_avail - cum[-1]),
               "stranded": stranded, "duration_s": float(len(xy) * self.dt),
               "replans": self.replans, "returned_early": self.returned_by_rule,
               "note": self.note}
        if np.isfinite(self.return_predicted_J):
            out.update(return_predicted_J=float(self.return_predicted_J),
                       return_reserve_J=float(self.return_reserve_J),
                       return_flown_J=float(np.sum(self.power[-1]) * self.dt))
        return out


def simulate_route(ctx: Context, xy, speed, truth, seed, rate,
                   energy_start_J: float = 0.0) -> SimResult:
    """Fly the route ``xy`` [m] at per-vertex ``speed`` [m/s] under ``truth`` (None: the
    scenario's own model), sampled at ``rate`` [Hz], from ``energy_start_J`` already drawn."""
    return simulate(ctx, Route(np.asarray(xy, float), np.asarray(speed, float), "bench mission"),
                    truth, seed=int(seed), sample_rate_Hz=rate,
                    energy_start_J=max(float(energy_start_J), 0.0))


def fly_open_loop(ctx: Context, plan, truth, seed: int, rate: float) -> dict:
    """(b) and (d): the tour flown as planned."""
    sim = simulate_route(ctx, plan.xy_m, plan.speed_mps, truth, seed, rate)
    flown = Flown(1.0 / rate, [], [], sim.energy_available_J)
    flown.add(sim.frame)
    return flown.outcome(ctx)


def stranding_upper_bound(k: int, n: int, level: float = 0.95) -> float | None:
    """One-sided Clopper-Pearson upper bound of the stranding probability [-]."""
    from scipy.stats import beta

    if n <= 0:
        return None
    return 1.0 if k >= n else float(beta.ppf(level, k + 1, n - k))
