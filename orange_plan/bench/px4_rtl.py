"""A PX4-style "return when the flight time left runs short" rule, flown in the simulator.

The rule (PX4-Autopilot, main branch; file names relative to its ``src/``):

* ``lib/battery/battery.cpp``, ``Battery::computeRemainingTime``: flight time left
  ``time_remaining_s = remaining capacity / average current``, the average being a first-order
  low-pass filter (``AlphaFilter``, time constant 50 s, ``_current_average_filter_a``)
  initialised with the parameter ``BAT_AVRG_CURRENT`` and updated while armed.
* ``modules/navigator/rtl_params.yaml`` (``RtlTimeEstimator::getEstimate`` in
  ``modules/navigator/rtl_time_estimator.cpp``): ``safe_time_estimate = RTL_TIME_FACTOR *
  time_estimate + RTL_TIME_MARGIN`` with defaults ``RTL_TIME_FACTOR = 1.1`` and
  ``RTL_TIME_MARGIN = 100 s``; ``time_estimate`` is the return path's horizontal length over
  the cruise speed (plus climb/descent and landing time, none for our robots).
* ``modules/commander/HealthAndArmingChecks/checks/batteryCheck.cpp``,
  ``BatteryChecks::rtlEstimateCheck``: the failsafe flag ``battery_low_remaining_time`` is
  raised when ``safe_time_estimate >= time_remaining_s``; its action is ``COM_FLTT_LOW_ACT``
  (default 3: Return).

Implemented here, in energy terms (our recordings carry battery power, not current):

    time_left_s(t)    = (E_usable - E_used(t)) / P_avg(t)
    P_avg             = low-pass of the recorded battery power, tau = 50 s, started at the
                        planning model's cruise power on flat ground (as BAT_AVRG_CURRENT)
    time_home_s(t)    = L_home(x(t)) / v_cruise,  L_home = length of the return path
    return at the first sample where  1.1 * time_home_s + 100 s >= time_left_s

``E_used`` integrates the recorded power (as PX4 integrates the measured current) and
``E_usable`` is the scenario's usable energy (PX4's ``BAT_CAPACITY``). The return path is the
minimum-energy roadmap path home (``planning.roadmap`` to-home field) from the nearest
visible roadmap vertex; ``L_home`` is that path's length, so the time estimate is of the path
actually flown home (PX4's ``RTL_TYPE = 0`` flies straight home, which obstacles forbid).
The 100 s margin is PX4's default kept for every robot: it is 15 % of the AR.Drone's
flight, < 1 % of the ground robots' (for them, effectively, only the x 1.1 remains).
Where the scenario has ``time_limit_s``, the same look-ahead also turns home when
``t + 1.1 * time_home_s + 100 s >= time_limit_s`` (PX4's ``COM_FLT_TIME_MAX`` acts only at
the limit; the look-ahead keeps the lawnmower inside the same mission window as the planner).

Flying it (``fly_with_return_rule``): simulate the whole lawnmower under the truth, find the
first sample where the rule fires, then simulate the route actually flown (the lawnmower up to
that point + the return path) under the same truth and seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from orange_plan.errors import InputError
from orange_plan.planning.homepaths import HomePaths
from orange_plan.planning.paths import clean_polyline, cut_path

RTL_TIME_FACTOR = 1.1
"""PX4 ``RTL_TIME_FACTOR`` default [-] (navigator/rtl_params.yaml)."""

RTL_TIME_MARGIN_S = 100.0
"""PX4 ``RTL_TIME_MARGIN`` default [s] (navigator/rtl_params.yaml)."""

CURRENT_AVERAGE_TAU_S = 50.0
"""Time constant of PX4's ``_current_average_filter_a`` [s] (lib/battery/battery.cpp)."""

RULE_RATE_HZ = 1.0
"""Rate at which the rule is evaluated on a recording [Hz]."""


@dataclass(frozen=True)
class ReturnRule:
    """PX4's remaining-flight-time return rule (see the module docstring).

    Attributes
    ----------
    time_factor : RTL_TIME_FACTOR [-]
    time_margin_s : RTL_TIME_MARGIN [s]
    power_tau_s : averaging time constant of the battery power [s]; ``math.inf``: the plain
        mean power since take-off
    """

    time_factor: float = RTL_TIME_FACTOR
    time_margin_s: float = RTL_TIME_MARGIN_S
    power_tau_s: float = CURRENT_AVERAGE_TAU_S

    def __post_init__(self):
        if not self.time_factor >= 1.0:
            raise InputError(f"time_factor = {self.time_factor!r} must be >= 1 (PX4 range 1..2)")
        if not self.time_margin_s >= 0.0:
            raise InputError(f"time_margin_s = {self.time_margin_s!r} must be >= 0")
        if not self.power_tau_s > 0.0:
            raise InputError(f"power_tau_s = {self.power_tau_s!r} must be > 0")

    def average_power_W(self, t_s, power_W, initial_W: float) -> np.ndarray:
        """Low-pass of the battery power at each sample [W] (PX4 ``AlphaFilter``).

        ``y_k = y_{k-1} + a_k (p_k - y_{k-1})`` with ``a_k = dt / (tau + dt)``, ``y_{-1} =
        initial_W``; with ``tau = inf`` the running mean of the samples so far.
        """
        t, p = np.asarray(t_s, float), np.asarray(power_W, float)
        if t.size == 0:
            return np.empty(0)
        if math.isinf(self.power_tau_s):
            return np.cumsum(p) / np.arange(1, p.size + 1)
        dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
        a = dt / (self.power_tau_s + dt)
        y, _ = lfilter([a], [1.0, a - 1.0], np.clip(p, 0.0, None), zi=[(1.0 - a) * initial_W])
        return y

    def safe_time_home_s(self, time_home_s):
        """``RTL_TIME_FACTOR * time_home + RTL_TIME_MARGIN`` [s]."""
        return self.time_factor * np.asarray(time_home_s, float) + self.time_margin_s

    def decide(self, ctx, frame, route_xy, home: HomePaths, cost=None) -> ReturnDecision:
        """Where this rule turns a simulated flight of ``route_xy`` home (``decide_return``)."""
        return decide_return(ctx, frame, route_xy, home, self)

    def first_return_index(self, t_s, energy_used_J, power_avg_W, time_home_s,
                           energy_usable_J: float, time_limit_s: float | None = None):
        """First sample at which the robot turns home, or None if it never has to.

        Fires where ``safe_time_home_s >= (energy_usable_J - energy_used_J) / power_avg_W``
        (PX4's ``battery_low_remaining_time``) or, with a time limit, where
        ``t_s + safe_time_home_s >= time_limit_s``.
        """
        used = np.asarray(energy_used_J, float)
        p = np.maximum(np.asarray(power_avg_W, float), 1e-9)
        safe = self.safe_time_home_s(time_home_s)
        time_left = (energy_usable_J - used) / p
        fire = safe >= time_left
        if time_limit_s is not None:
            fire |= np.asarray(t_s, float) + safe >= time_limit_s
        return int(np.argmax(fire)) if fire.any() else None


def cruise_power_W(ctx, speed_mps: float) -> float:
    """Battery power at cruise on flat default ground, stops included (BAT_AVRG_CURRENT) [W]."""
    from orange_plan.physics.range import flat_state

    state = flat_state(speed_mps, ctx.world.default_crr, ctx.conditions.sensor_rate_Hz)
    e = ctx.model.segment_energy(state, 1.0, ctx.conditions.duty_cycle)
    return float(e.total_J / e.mission_time_s)


@dataclass(frozen=True)
class ReturnDecision:
    """Where the rule turned the robot home in the first (whole-lawnmower) simulation.

    Attributes
    ----------
    fired : the rule fired (else the lawnmower was finished and the robot came home)
    t_s : mission time of the turn [s]
    xy_m : position of the turn [m]
    s_m : arclength along the lawnmower of the turn [m]
    time_home_s, time_left_s : PX4's time estimate home and flight time left then [s]
    """

    fired: bool
    t_s: float
    xy_m: tuple[float, float]
    s_m: float
    time_home_s: float
    time_left_s: float


def decide_return(ctx, frame, lawn_xy, home: HomePaths, rule: ReturnRule) -> ReturnDecision:
    """Apply the rule to a simulated recording of the lawnmower (``frame``: the recording columns of docs/formats.md)."""
    t = frame["t_s"].to_numpy(float)
    power = frame["power_W"].to_numpy(float)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    used = np.cumsum(power) * dt
    avg = rule.average_power_W(t, power, cruise_power_W(ctx, home.speed_mps))
    every = max(1, round(1.0 / (RULE_RATE_HZ * dt)))
    idx = np.arange(0, t.size, every)
    xy = frame[["x_m", "y_m"]].to_numpy(float)
    time_home = home.time_s(xy[idx])
    usable = ctx.scenario.battery.usable_J
    i = rule.first_return_index(t[idx], used[idx], avg[idx], time_home, usable,
                                ctx.scenario.mission.time_limit_s)
    if i is None:
        return ReturnDecision(False, float(t[-1]), tuple(xy[-1]), _length(lawn_xy), 0.0,
                              float((usable - used[-1]) / max(avg[-1], 1e-9)))
    k = idx[i]
    s = locate_on_path(lawn_xy, xy[k], _distance_driven(frame, dt, k))
    return ReturnDecision(True, float(t[k]), tuple(float(v) for v in xy[k]), s,
                          float(time_home[i]), float((usable - used[k]) / max(avg[k], 1e-9)))


@dataclass(frozen=True)
class EnergyRule:
    """The session's energy rule, applied to a simulated flight (``bench plan`` (c) and (e)).

    At each rule sample (``RULE_RATE_HZ``) the robot turns home at the first sample where

        E_used(t) + k(t) E_home(x) + reserve_return(k E_home, k^2 var_home) >= E_usable

    (plus the draw of two check intervals at the recent power: the robot turns before the
    check that would fail) or, with a time limit, ``t + time_factor * T_home(x) >=
    time_limit_s``. ``E_used`` is the
    measured energy (recorded power, integrated as PX4 integrates current); ``E_home`` and
    its predictive variance are the planning model's for the way home from the position
    (``HomePaths.returns``); ``reserve_return`` is the scenario's reserve for the uncertainty
    of the return alone (``ReserveRule.return_only_J``: the energy already spent is measured,
    not predicted, as in ``MissionSession.decision``); ``k`` is what the run has taught so
    far: the measured energy over the planning model's prediction for the path flown, once
    ``learn_share`` of the usable energy is spent (before: 1), never below 1 - a cheaper
    run does not shrink the way home.

    Attributes
    ----------
    time_factor : the time home is taken this much longer (ramps and stops) [-]
    learn_share : share of the usable energy spent before the run's ratio is used [-]
    power_window_s : time constant of the recent power that sizes the look-ahead of two
        check intervals [s]
    """

    time_factor: float = 1.05
    learn_share: float = 0.05
    power_window_s: float = 10.0

    def decide(self, ctx, frame, route_xy, home: HomePaths, cost=None) -> ReturnDecision:
        from orange_plan.planning.lawnmower import cumulative_energy_time
        from orange_plan.planning.reserve import reserve_from

        t = frame["t_s"].to_numpy(float)
        power = frame["power_W"].to_numpy(float)
        dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
        used = np.cumsum(power) * dt
        every = max(1, round(1.0 / (RULE_RATE_HZ * dt)))
        idx = np.arange(0, t.size, every)
        xy = frame[["x_m", "y_m"]].to_numpy(float)
        usable = ctx.scenario.battery.usable_J
        back, var, back_m = home.returns(xy[idx], ctx.model)
        ratio = np.ones(idx.size)
        if cost is not None and idx.size > 1:
            # the prediction for the distance driven along the route (the recorded positions
            # are noisy: their heading changes would count as turning energy)
            route = np.asarray(route_xy, float)
            along = np.r_[0.0, np.cumsum(np.hypot(*np.diff(route, axis=0).T))]
            driven = np.cumsum(frame["v_mps"].to_numpy(float))[idx] * dt
            predicted = np.interp(driven, along, cumulative_energy_time(ctx, cost, route)[0])
            learnt = predicted >= self.learn_share * usable
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = np.where(learnt, np.maximum(used[idx] / predicted, 1.0), 1.0)
        reserve = reserve_from(ctx.scenario).return_only_J(ratio * back, ratio**2 * var, usable)
        # the draw until the next check and the turn itself: two check intervals at the
        # recent power (a check that only just passes may be exceeded before the next one)
        a = dt / (self.power_window_s + dt)
        recent = lfilter([a], [1.0, a - 1.0], np.clip(power, 0.0, None))[idx]
        ahead = 2.0 * recent / RULE_RATE_HZ
        fire = used[idx] + ahead + ratio * back + reserve >= usable
        time_home = self.time_factor * back_m / (home.speed_mps * ctx.conditions.duty_cycle)
        limit = ctx.scenario.mission.time_limit_s
        if limit is not None:
            fire |= t[idx] + time_home >= limit
        if not fire.any():
            return ReturnDecision(False, float(t[-1]), tuple(xy[-1]), _length(route_xy), 0.0,
                                  float(limit - t[-1]) if limit is not None else math.inf)
        i = int(np.argmax(fire))
        k = idx[i]
        s = locate_on_path(route_xy, xy[k], _distance_driven(frame, dt, k))
        return ReturnDecision(True, float(t[k]), tuple(float(v) for v in xy[k]), s,
                              float(time_home[i]), float(usable - used[k]))


def _length(xy) -> float:
    return float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))


def _distance_driven(frame, dt: float, k: int) -> float:
    return float(np.sum(frame["v_mps"].to_numpy(float)[:k]) * dt)


def locate_on_path(xy, point, s_hint_m: float, window: float = 0.1) -> float:
    """Arclength of the point of a polyline nearest ``point`` within ``s_hint_m`` +- 10 % (a
    path that crosses itself is otherwise ambiguous) [m]."""
    xy = np.asarray(xy, float)
    p = np.asarray(point, float)
    a, b = xy[:-1], xy[1:]
    seg = np.hypot(*(b - a).T)
    s0 = np.r_[0.0, np.cumsum(seg)]
    tol = window * s_hint_m + 20.0
    near = (s0[1:] >= s_hint_m - tol) & (s0[:-1] <= s_hint_m + tol)
    if not near.any():
        near[:] = True
    j = np.flatnonzero(near)
    d = b[j] - a[j]
    u = np.clip(np.einsum("ij,ij->i", p - a[j], d) / np.maximum(np.einsum("ij,ij->i", d, d),
                                                                  1e-18), 0.0, 1.0)
    dist = np.hypot(*(a[j] + u[:, None] * d - p).T)
    m = int(np.argmin(dist))
    return float(s0[j[m]] + u[m] * seg[j[m]])


def flown_route(lawn_xy, decision: ReturnDecision, home: HomePaths) -> np.ndarray:
    """The route actually flown: the lawnmower up to the turn, then the return path [m]."""
    if not decision.fired:
        return np.asarray(lawn_xy, float)
    prefix = cut_path(lawn_xy, decision.s_m)
    back = home.path(prefix[-1])
    return clean_polyline(np.vstack([prefix, back[1:]]))


SIM_ENERGY_FACTOR = 1.6
"""The first (whole-lawnmower) simulation stops where the planning model has used this many
times the usable energy: no truth within the calibration uncertainty flies that far."""


def simulation_horizon(ctx, cost, lawn_xy, factor: float = SIM_ENERGY_FACTOR) -> np.ndarray:
    """The lawnmower cut where the planning model has used ``factor`` x the usable
    energy (or 1.5 x the time limit plus an hour) [m]; the whole path if it ends before."""
    from orange_plan.planning.lawnmower import cumulative_energy_time

    lawn_xy = np.asarray(lawn_xy, float)
    energy, t = cumulative_energy_time(ctx, cost, lawn_xy)
    over = energy >= factor * ctx.scenario.battery.usable_J
    limit = ctx.scenario.mission.time_limit_s
    if limit is not None:
        over |= t >= 1.5 * limit + 3600.0
    if not over.any():
        return lawn_xy
    return lawn_xy[: int(np.argmax(over)) + 1]


def fly_with_return_rule(ctx, lawn_xy, home: HomePaths, truth, seed: int,
                         rule=ReturnRule(), cost=None, sample_rate_Hz: float = 10.0):
    """Fly a route (the lawnmower, or a plan and its continuation) under ``truth`` and turn
    home by ``rule``: PX4's ``ReturnRule`` or the session's ``EnergyRule`` (module
    docstring).

    Returns
    -------
    (SimResult of the route actually flown, ReturnDecision, that route's vertices [m])
    """
    from orange_plan.sim.route import Route
    from orange_plan.sim.simulator import simulate

    lawn_xy = np.asarray(lawn_xy, float)
    for factor in SIM_ENERGY_FACTOR * 2.0 ** np.arange(4):
        first = lawn_xy if cost is None else simulation_horizon(ctx, cost, lawn_xy, factor)
        speed = np.full(len(first), home.speed_mps)
        sim1 = simulate(ctx, Route(first, speed, "lawnmower"), truth, seed=seed,
                        sample_rate_Hz=sample_rate_Hz)
        decision = rule.decide(ctx, sim1.frame, first, home, cost)
        if decision.fired or len(first) == len(lawn_xy):
            break  # else the truth is cheaper than the horizon assumed: fly farther
    route = flown_route(lawn_xy, decision, home)
    if not decision.fired and len(first) == len(lawn_xy):
        return sim1, decision, route
    sim2 = simulate(ctx, Route(route, np.full(len(route), home.speed_mps), "lawnmower + RTL"),
                    truth, seed=seed, sample_rate_Hz=sample_rate_Hz)
    return sim2, decision, route
