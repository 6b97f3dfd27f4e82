"""Mid-mission replanning: telemetry in, a decision out, and a new tour when the world or the
robot turns out different from the plan.

Problem statement (kept apart from how it is solved): during a mission the robot reports
samples (time, battery power, position, ...). After each batch the operator needs to know
whether the robot should

- ``return_home`` now: with what it has measured so far, the way home and its reserve no
  longer fit the energy left, or getting home is less likely than the reserve promises;
- ``replan``: the robot can still get home, but the plan it flies was made for another
  robot or another map (the energy it measures departs from the plan's model, a map update
  arrived, or the rest of the tour no longer keeps the homing constraint);
- ``continue`` otherwise;

and, on a replan, a new tour from the current position, energy, time and area already
sensed, made with the model the telemetry has taught (a head wind or a heavier load
shrinks it, a lighter one may extend it), in the world with every map update.

Decision rule (``MissionSession.decision``), in this order, with ``E_avail`` the usable
battery energy (the scenario's, or less when the telemetry's state of charge shows a smaller
battery: ``identify.soc``), ``E_used`` the measured battery energy so far (sum of ``P dt``),
``E_home`` the energy of the best roadmap return from the current position evaluated with
the online model, ``R`` the scenario's reserve for that return and ``sd_home`` its predictive
standard deviation:

1. ``return_home`` when ``margin = E_avail - E_used - E_home - R < 0``, or the reserve is a
   confidence ``p`` and ``P(home) = Phi((E_avail - E_used - E_home) / sd_home) < p``.
2. ``replan`` when the map changed since the plan was made; or the energy per metre measured
   over the estimator's window departs from the plan model's prediction for the same motion
   by more than ``DEPARTURE_Z`` predictive standard deviations of the online estimator
   (``energy_per_m_sd_J``); or the rest of the tour, re-evaluated with the online model,
   has a vertex where ``E_used + E(here -> v) + E_home(v) + R(v) > E_avail - replan_margin_J``.
3. ``continue`` otherwise.

``remaining_range_m = max(0, E_avail - E_used - R) / e``, with ``e`` the online energy per
metre over the recent motion (the plan model's flat-ground figure before any motion).

How it is solved: ``identify.online.OnlineEstimator`` updates the model's coefficients and
covariance from every batch (recursive least squares with forgetting) and measures the energy
used; the return home is the cheapest roadmap way home (``planning.reach.way_home``) driven
from rest to rest and re-evaluated exactly (``planning.tour.drive``, the same evaluation as
the tour's returns) with the online coefficients, and its variance is ``g' Cov g`` (online
covariance) plus the estimator's spread of the energy per metre in quadrature; a replan is
``planning.tour.plan_tour`` from a ``StartState`` with the online model and the updated world.

Why the answer is safe: ``continue`` and ``replan`` are only said when the current position
has a return home whose exact energy with the model the data supports, plus the reserve,
fits what is left; a new tour is only returned by ``plan_tour``, which keeps the homing
constraint at every vertex with that model. Replay is deterministic: the same events (sample
batches, map updates, adopted plans) in the same order rebuild the same session
(``state_dict`` / ``from_state``; replans are stored, not recomputed).
"""

from __future__ import annotations

import json
import math
from collections import deque
from dataclasses import asdict, dataclass, replace

import numpy as np
import pandas as pd
import shapely
from scipy.spatial import cKDTree
from scipy.stats import norm
from shapely.geometry import shape

from orange_plan.errors import InputError
from orange_plan.identify.online import WINDOW_PARTS, OnlineEstimator
from orange_plan.identify.soc import SocCapacity
from orange_plan.physics.pathcost import path_energy
from orange_plan.physics.state import MotionState
from orange_plan.planning.coverage import footprint
from orange_plan.planning.paths import distinct_vertices
from orange_plan.planning.plan import Plan, StartState
from orange_plan.planning.reach import prepare_reach, reserve_J, way_home
from orange_plan.telemetry.recording import recording_from_frame
from orange_plan.telemetry.state import recording_state
from orange_plan.world.geomap import keep_out_polygon

ACTIONS = ("continue", "replan", "return_home")
DEPARTURE_Z = 3.0
"""Predictive standard deviations of the energy per metre beyond which the measured rate is
said to depart from the plan's model (three: a false alarm about once in 370 windows)."""
CONTEXT_ROWS = 8
"""Earlier samples prepended to a batch so speeds and yaw rates derived from positions
(centred differences over ``SMOOTH_WINDOW_S``) are continuous across batches."""
STATE_VERSION = 1
"""Version of the ``state_dict`` layout."""


@dataclass(frozen=True)
class Decision:
    """What the robot should do now, and the figures it rests on.

    Attributes
    ----------
    action : "continue", "replan" or "return_home"
    reason : one sentence a person can check against the figures
    position_xy_m : last reported position [m]
    energy_used_J : measured battery energy so far [J]
    time_s : mission time of the last sample [s]
    energy_to_home_J : energy of the return home from the position, online model [J]
    reserve_J : reserve kept for that return (the scenario's rule) [J]
    homing_margin_J : energy_available - energy_used - energy_to_home - reserve [J]
    return_probability : probability that the energy left covers the return [-]
    remaining_range_m : (energy left - reserve) / online energy per metre [m]
    covered_m2 : area sensed so far (sensor footprint along the trail) [m^2]
    energy_available_J : usable battery energy the decision counts on [J]: the scenario's,
        or less when the telemetry's ``soc`` shows a smaller battery (``capacity_from_soc``)
    """

    action: str
    reason: str
    position_xy_m: tuple[float, float]
    energy_used_J: float
    time_s: float
    energy_to_home_J: float
    reserve_J: float
    homing_margin_J: float
    return_probability: float
    remaining_range_m: float
    covered_m2: float
    energy_available_J: float = math.nan

    def to_dict(self) -> dict:
        d = asdict(self)
        d["position_xy_m"] = list(self.position_xy_m)
        return d


@dataclass
class _Batch:
    """One telemetry batch as the estimator's window keeps it."""

    duration_s: float
    distance_m: float
    measured_J: float
    state: MotionState
    dt: np.ndarray
    wind_dt_m: tuple[float, float]  # time integrals of the wind (the window's mean wind)
    planned_J: float | None = None  # this motion's energy under the plan's model (lazily)


@dataclass(frozen=True)
class _Home:
    """The return home from the current position."""

    energy_J: float
    reserve_J: float
    sd_J: float


class MissionSession:
    """A mission in progress: plan, telemetry, online model, decisions and replans.

    Parameters
    ----------
    ctx : Context (scenario, world, model) the mission was planned in
    plan : the plan being flown; None: plan the first tour from home here
    n_vertices, seed : roadmap size and seed of replans and of the return-home roadmap
    replan_margin_J : homing margin [J] the rest of the tour must keep (re-evaluated with the
        online model) before a replan is advised; default 0
    planner_kwargs : extra keyword arguments of ``plan_tour`` (default: BIT* refinement off,
        so a replan depends only on its inputs and the seed)
    memory_s, window_s : the online estimator's forgetting time and energy-per-metre window [s]

    Attributes
    ----------
    plan : the current plan
    ctx : the current context (its world gains the map updates)
    """

    def __init__(self, ctx, plan: Plan | None = None, *, n_vertices: int = 3000, seed: int = 0,
                 replan_margin_J: float | None = None, planner_kwargs: dict | None = None,
                 memory_s: float = 300.0, window_s: float = 300.0):
        margin = 0.0 if replan_margin_J is None else float(replan_margin_J)
        if not math.isfinite(margin):
            raise InputError(f"replan_margin_J = {replan_margin_J!r} must be a finite number")
        if not (isinstance(n_vertices, int) and n_vertices >= 10):
            raise InputError(f"n_vertices = {n_vertices!r} must be an integer >= 10")
        self.ctx = ctx
        self.n_vertices, self.seed, self.replan_margin_J = n_vertices, int(seed), margin
        self.planner_kwargs = {"bitstar_legs": 0, **(planner_kwargs or {})}
        self.memory_s, self.window_s = float(memory_s), float(window_s)
        self._estimator = OnlineEstimator(ctx.model, ctx.scenario.battery.usable_J,
                                          memory_s=memory_s, window_s=window_s)
        self._events: list[dict] = []
        self._soc = SocCapacity()
        self._history = pd.DataFrame()
        self._window: deque[_Batch] = deque()
        self._batch_cache: dict = {}
        if plan is None:
            plan = self._plan(StartState())
        self._initial_plan = plan
        self._energy_start_J = float(plan.energy_used_J[0])
        self.trail_xy_m = np.asarray(plan.xy_m[:1], float).reshape(-1, 2)
        self.covered = shapely.GeometryCollection()
        self.time_s = float(plan.t_s[0])
        self._t_last: float | None = None
        self._adopt(plan)

    # --- state ---------------------------------------------------------------------------
    @property
    def energy_used_J(self) -> float:
        """Measured battery energy so far, sum of P dt [J] (plus the plan's start energy)."""
        return self._energy_start_J + self._estimator.energy_used_J

    @property
    def position_xy_m(self) -> tuple[float, float]:
        return (float(self.trail_xy_m[-1, 0]), float(self.trail_xy_m[-1, 1]))

    @property
    def energy_available_J(self) -> float:
        """Usable energy counted on [J]: the scenario's, or the smaller capacity the
        telemetry's state of charge shows (``capacity_from_soc``): an aged battery must not
        be spent as if it were new."""
        claimed = float(self.ctx.scenario.battery.usable_J)
        shown = self._soc.usable_J()
        return claimed if shown is None else min(claimed, shown)

    @property
    def capacity_shortfall_J(self) -> float:
        """Scenario usable energy minus the energy counted on [J] (>= 0)."""
        return float(self.ctx.scenario.battery.usable_J) - self.energy_available_J

    @property
    def online_model(self):
        """The scenario model with the estimator's coefficients and covariance."""
        def build():
            est = self._estimator
            return self.ctx.model.with_theta(dict(zip(self.ctx.model.names, est.theta_)),
                                             est.cov_)
        return self._per_batch("online_model", build)

    @property
    def conditions_now(self):
        """The context's conditions with the wind measured over the window (the scenario's
        wind where the samples carry none)."""
        def build():
            duration = sum(b.duration_s for b in self._window)
            if duration <= 0:
                return self.ctx.conditions
            wx = sum(b.wind_dt_m[0] for b in self._window)
            wy = sum(b.wind_dt_m[1] for b in self._window)
            return self.ctx.conditions.with_wind((wx / duration, wy / duration))
        return self._per_batch("conditions_now", build)

    def _estimate(self):
        """The online estimator's figures after the last batch."""
        return self._per_batch("estimate", self._estimator.estimate)

    def _per_batch(self, name: str, build):
        """A figure that only changes when a batch arrives or the map changes, built once
        between those events (a decision reads each several times)."""
        cache = self._batch_cache
        if name not in cache:
            cache[name] = build()
        return cache[name]

    def _new_batch(self) -> None:
        self._batch_cache = {}

    def _adopt(self, plan: Plan) -> None:
        """Fly ``plan`` from now on; its figures were made with the current online model
        and world."""
        self.plan = plan
        self._plan_model = self.online_model
        self._plan_conditions = self.conditions_now
        self._progress = 0
        for b in self._window:
            b.planned_J = None  # a new plan model: predict again
        self._map_changed = False
        self._home_reach = None

    # --- telemetry -----------------------------------------------------------------------
    def feed(self, samples) -> Decision:
        """Take a batch of samples and return the decision after it.

        Parameters
        ----------
        samples : pandas DataFrame or list of dicts with the recording columns: ``t_s`` [s],
            ``power_W`` [W] (or ``voltage_V`` and ``current_A``), ``x_m``, ``y_m`` [m], and
            optionally ``v_mps``, ``yaw_rate_radps``, ``wind_mps``, ``wind_from_deg``... (any
            other column is kept and ignored)

        Raises
        ------
        InputError
            One line: a missing column, a non-numeric or non-finite value in a needed column,
            time not increasing (within the batch or against the previous batch).
        """
        frame = self._validated(samples)
        self._ingest(frame)
        self._events.append({"feed": frame})  # as JSON records only when state_dict asks
        return self.decision()

    def _validated(self, samples) -> pd.DataFrame:
        if isinstance(samples, pd.DataFrame):
            frame = samples.reset_index(drop=True).copy()
        else:
            try:
                frame = pd.DataFrame(list(samples))
            except (TypeError, ValueError) as exc:
                raise InputError(f"samples must be a DataFrame or a list of dicts ({exc})") from None
        if len(frame) == 0:
            raise InputError("samples: the batch is empty")
        power = ["power_W"] if "power_W" in frame else ["voltage_V", "current_A"]
        needed = ["t_s", *power, "x_m", "y_m"]
        missing = [c for c in needed if c not in frame]
        if missing:
            raise InputError(f"samples: missing column(s) {missing} (need t_s, power_W or "
                             "voltage_V and current_A, x_m, y_m)")
        for col in needed:
            floats = frame[col].dtype == np.float64  # JSON numbers: no text to convert
            values = (frame[col].to_numpy() if floats
                      else pd.to_numeric(frame[col], errors="coerce").to_numpy(float))
            bad = np.flatnonzero(~np.isfinite(values))
            if bad.size:
                raise InputError(f"samples: {col} is not a finite number at row {int(bad[0])} "
                                 f"({frame[col].iloc[int(bad[0])]!r})")
            if not floats:
                frame[col] = values
        t = frame["t_s"].to_numpy(float)
        prev = np.r_[self._t_last if self._t_last is not None else -np.inf, t[:-1]]
        back = np.flatnonzero(t <= prev)
        if back.size:
            i = int(back[0])
            raise InputError(f"samples: t_s does not increase at row {i} ({t[i]:g} s after "
                             f"{prev[i]:g} s)")
        if "power_W" not in frame:
            frame["power_W"] = frame["voltage_V"] * frame["current_A"]
        return frame

    def _ingest(self, frame: pd.DataFrame) -> None:
        """Energy, estimator, trail and covered area from a validated batch."""
        self._new_batch()
        history = pd.concat([self._history, frame], ignore_index=True)
        t = frame["t_s"].to_numpy(float)
        xy = frame[["x_m", "y_m"]].to_numpy(float)
        dt = np.diff(np.r_[t[0] if self._t_last is None else self._t_last, t])
        if len(history) >= 2:
            context = history.tail(len(frame) + CONTEXT_ROWS)
            rec = recording_from_frame(context, "samples")
            state = recording_state(rec, self.ctx.world, conditions=self.ctx.conditions)
            state = state.take(slice(len(rec.frame) - len(frame), None), len(rec.frame))
            state = state.with_(elapsed_s=t - float(history["t_s"].iloc[0]))
            power = frame["power_W"].to_numpy(float)
            used_before = self.energy_used_J
            self._estimator.update(state, power, dt)
            if "soc" in frame:
                self._soc.add(used_before + np.cumsum(power * dt),
                              pd.to_numeric(frame["soc"], errors="coerce").to_numpy(float))
            speed = np.asarray(state.speed_mps, float) * np.ones(len(t))
            self._remember(float(dt.sum()), float(np.sum(speed * dt)), float(power @ dt),
                           state, dt)
        self._history = history.tail(CONTEXT_ROWS).reset_index(drop=True)
        r = self.ctx.scenario.mission.sensor_radius_m
        seen = footprint(self.ctx.world, np.vstack([self.trail_xy_m[-1:], xy]), r)
        self.covered = seen if self.covered.is_empty else self.covered.union(seen)
        self.trail_xy_m = np.vstack([self.trail_xy_m, xy])
        self.time_s = float(t[-1])
        self._t_last = float(t[-1])
        self._progress = self._tour_progress()

    def _remember(self, duration_s, distance_m, measured_J, state, dt) -> None:
        """Keep the last ``window_s`` of batches: what was measured and the motion, so any
        model's prediction for the same motion can be made."""
        wind = tuple(float(np.sum(np.asarray(w) * dt))
                     for w in (state.wind_x_mps, state.wind_y_mps))
        self._window.append(_Batch(duration_s, distance_m, measured_J, state, dt, wind))
        span = sum(b.duration_s for b in self._window)
        while len(self._window) > 1 and span - self._window[0].duration_s >= self.window_s:
            span -= self._window.popleft().duration_s

    def _tour_progress(self) -> int:
        """Index of the tour segment the robot is on: the first one, from the last progress
        on, within half a footprint of the nearest (a tour may pass a place twice)."""
        xy = self.plan.xy_m
        if len(xy) < 2:
            return 0
        a, b = xy[self._progress:-1], xy[self._progress + 1:]
        d = _distance_to_segments(np.asarray(self.position_xy_m), a, b)
        near = d <= d.min() + 0.5 * self.ctx.scenario.mission.sensor_radius_m
        return self._progress + int(np.argmax(near))

    # --- decision ------------------------------------------------------------------------
    def decision(self) -> Decision:
        """The decision now (module docstring: decision rule)."""
        used = self.energy_used_J
        avail = self.energy_available_J
        home = self._return_home()
        margin = avail - used - home.energy_J - home.reserve_J
        prob = _probability(avail - used - home.energy_J, home.sd_J)
        res_rule = self.ctx.scenario.mission.reserve
        left = max(avail - used - home.reserve_J, 0.0)
        per_m = self._energy_per_m_J()
        figures = dict(
            position_xy_m=self.position_xy_m, energy_used_J=used, time_s=self.time_s,
            energy_to_home_J=home.energy_J, reserve_J=home.reserve_J, homing_margin_J=margin,
            return_probability=prob, remaining_range_m=left / per_m if per_m > 0 else math.inf,
            covered_m2=float(self.covered.area), energy_available_J=avail)
        if not math.isfinite(home.energy_J):
            return Decision("return_home", "no way home was found from the current position; "
                            "head home by the last known way", **figures)
        if margin < 0:
            return Decision("return_home", f"the homing margin is {margin:,.0f} J: "
                            f"{used:,.0f} J used + {home.energy_J:,.0f} J to home + "
                            f"{home.reserve_J:,.0f} J reserve exceed {avail:,.0f} J available",
                            **figures)
        if res_rule.kind == "confidence" and prob < res_rule.value:
            return Decision("return_home", f"the probability of getting home is {prob:.4f}, "
                            f"below the reserve's confidence {res_rule.value:g}", **figures)
        reason = self._replan_reason(used, avail)
        if reason is not None:
            return Decision("replan", reason, **figures)
        return Decision("continue", f"home is {home.energy_J:,.0f} J away with "
                        f"{margin:,.0f} J to spare after the {home.reserve_J:,.0f} J reserve, "
                        "and the plan still fits the measured energy", **figures)

    def _replan_reason(self, used: float, avail: float) -> str | None:
        if self._map_changed:
            return "the map changed since the plan was made"
        departure = self._departure()
        if departure is not None:
            measured, predicted, sd = departure
            if abs(measured - predicted) > DEPARTURE_Z * sd:
                return (f"the measured energy per metre {measured:.2f} J/m departs from the "
                        f"plan's {predicted:.2f} J/m by more than {DEPARTURE_Z:g} x "
                        f"{sd:.2f} J/m (the online predictive spread)")
        worst = self._remaining_tour_margin_J(used, avail)
        if worst < self.replan_margin_J:
            return (f"the rest of the tour, re-evaluated with the online model, leaves a "
                    f"homing margin of {worst:,.0f} J < {self.replan_margin_J:,.0f} J")
        return None

    def _departure(self):
        """(measured, plan-model predicted, predictive sd) energy per metre over the window
        [J/m], or None while the window is too short to have a spread."""
        if len(self._window) < 2 * WINDOW_PARTS:
            return None
        dist = sum(b.distance_m for b in self._window)
        if dist <= 0:
            return None
        measured = sum(b.measured_J for b in self._window) / dist
        # the plan's prediction: its model under its conditions (its wind), on the motion driven
        wx, wy = self._plan_conditions.wind_xy_mps
        for b in self._window:  # each batch once per plan (a window holds up to ~150)
            if b.planned_J is None:
                b.planned_J = float(np.sum(np.asarray(self._plan_model.power_W(
                    b.state.with_(wind_x_mps=wx, wind_y_mps=wy)), float) * b.dt))
        predicted = sum(b.planned_J for b in self._window) / dist
        sd = self._estimate().energy_per_m_sd_J
        if not (math.isfinite(sd) and sd > 0):
            return None
        return measured, predicted, sd

    def _energy_per_m_J(self) -> float:
        """Online energy per metre of the recent motion; the plan model's flat-ground figure
        before the robot has moved [J/m]."""
        e = self._estimate().energy_per_m_J
        if math.isfinite(e) and e > 0:
            return float(e)
        from orange_plan.physics.range import simplified_range

        return simplified_range(self.ctx.scenario, self.online_model,
                                self.ctx.world.default_crr).energy_per_m_J

    def _return_home(self) -> _Home:
        """Best roadmap return from the position, driven from rest to rest and evaluated with
        the online model (energy and gradient from one drive, as the tour's returns)."""
        from orange_plan.planning.tour import drive

        reach, tree = self._reach()
        model = self.online_model
        exact = replace(reach.exact, model=model, world=self.ctx.world,
                        conditions=self.conditions_now)
        for xy in self._free_positions():
            back = way_home(replace(reach, exact=exact), xy, tree)
            if back is None:
                continue
            if len(back) < 2:  # at home
                return _Home(0.0, float(reserve_J(self.ctx.scenario.mission.reserve,
                                                  self.energy_available_J, 0.0)), 0.0)
            driven = drive(exact, back, exact.speed_mps)
            energy = float(driven.energy_J[-1])
            var = float(model.energy_variance_J2(driven.gradient[-1]))
            spread = self._relative_spread() * energy
            sd = math.sqrt(max(var, 0.0) + spread**2)
            res = float(reserve_J(self.ctx.scenario.mission.reserve, self.energy_available_J,
                                  sd**2))
            return _Home(energy, res, sd)
        return _Home(math.inf, 0.0, 0.0)

    def _free_positions(self):
        """The position, or (GPS noise beside an obstacle) the latest free trail point."""
        world = self.ctx.world
        recent = self.trail_xy_m[::-1][:200]
        free = world.is_free(recent[:, 0], recent[:, 1])
        for i in np.flatnonzero(free)[:3]:
            yield tuple(float(v) for v in recent[i])

    def _relative_spread(self) -> float:
        """The online estimator's predictive sd of the energy per metre over its value
        (conditions: gusts, terrain, stops) [-]; 0 before it can say."""
        est = self._estimate()
        e, sd = est.energy_per_m_J, est.energy_per_m_sd_J
        return float(sd / e) if (math.isfinite(e) and e > 0 and math.isfinite(sd)) else 0.0

    def _reach(self):
        """Roadmap and to-home field of the current world, and a k-d tree of its vertices
        (built once per map version)."""
        if self._home_reach is None:
            reach = prepare_reach(self.ctx, None, 0.0, n_vertices=self.n_vertices,
                                  seed=self.seed, with_gradient=False)
            self._home_reach = (reach, cKDTree(reach.roadmap.xy_m))
        return self._home_reach

    def _remaining_tour_margin_J(self, used: float, avail: float) -> float:
        """Smallest homing margin over the rest of the tour with the online model [J].

        The rest of the tour is driven from the position at the plan's speeds and costed
        exactly with the online model; each vertex's planned return and (confidence) reserve
        are scaled by the ratio of online to planned energy of that rest, the same
        terrain driven by both models.
        """
        plan, k = self.plan, self._progress
        rest = np.vstack([self.position_xy_m, plan.xy_m[k + 1:]])
        keep = distinct_vertices(rest)
        speeds = plan.speed_mps[k:-1][keep[1:]]
        rest = rest[keep]
        if len(rest) < 2:
            return avail - used - float(plan.reserve_J[-1])
        world = self.ctx.world
        online = path_energy(self.online_model, world, rest, speeds,
                             self.conditions_now).cumulative_J
        planned = path_energy(self._plan_model, world, rest, speeds,
                              self._plan_conditions).cumulative_J
        ratio = online[-1] / planned[-1] if planned[-1] > 0 else 1.0
        idx = np.r_[k, k + 1 + np.flatnonzero(keep[1:])]
        to_home = plan.energy_to_home_J[idx] * ratio
        res = plan.reserve_J[idx]
        if self.ctx.scenario.mission.reserve.kind == "confidence":
            res = res * ratio
        return float(np.min(avail - used - online - to_home - res))

    # --- replanning ----------------------------------------------------------------------
    def replan(self) -> Plan:
        """A new tour from the current position, energy, time and covered area, with the
        online model and the current world; it becomes the session's plan.

        Raises
        ------
        InputError
            When no tour fits (e.g. the robot should go home: the battery left cannot visit
            anything new and come back).
        """
        # a battery smaller than the scenario's is planned as that much energy already spent
        start = StartState(self.position_xy_m, self.energy_used_J + self.capacity_shortfall_J,
                           self.time_s, None if self.covered.is_empty else self.covered)
        plan = self._plan(start)
        self._events.append({"plan": plan.to_geojson()})
        self._adopt(plan)
        return plan

    def _plan(self, start: StartState) -> Plan:
        """A tour with the online model and the current world. The first plan builds the
        roadmap and candidate legs; later replans reuse them (``tour.TourPlanner``: a warm
        replan only adds the robot's position to the roadmap), unless the map changed."""
        from orange_plan.planning.tour import TourPlanner

        if getattr(self, "_planner", None) is None:
            self._planner = TourPlanner(self.ctx, n_vertices=self.n_vertices, seed=self.seed,
                                        **self.planner_kwargs)
        return self._planner.plan(start, model=self.online_model, world=self.ctx.world,
                                  conditions=self.conditions_now)

    # --- map updates ---------------------------------------------------------------------
    def update_map(self, obstacles=(), no_go=(), replan: bool = True) -> Decision:
        """Add obstacles and no-go zones (map frame) and, by default, replan around them.

        Parameters
        ----------
        obstacles, no_go : shapely Polygons/MultiPolygons, GeoJSON geometry dicts, or
            coordinate lists (a ring ``[[x, y], ...]`` or a Polygon's list of rings) [m]
        replan : plan a new tour now (else the next decision says "replan")

        Raises
        ------
        InputError
            A polygon that breaks the rules of a map file (``world.geomap.keep_out_polygon``:
            malformed, a ring not closed, a coordinate not finite or too far, invalid, empty,
            or outside the boundary), or that covers the robot's position or home (one
            line, naming which polygon).
        """
        boundary = self.ctx.world.map.boundary  # a map file's rules (world.geomap)
        new_obstacles = [keep_out_polygon(p, f"map update: obstacles[{i}]", boundary)
                         for i, p in enumerate(obstacles)]
        new_no_go = [keep_out_polygon(p, f"map update: no_go[{i}]", boundary)
                     for i, p in enumerate(no_go)]
        where = {"the robot's position": self.position_xy_m, "home": self.ctx.world.home_xy_m}
        for name, poly in [*(("obstacles", p) for p in new_obstacles),
                           *(("no_go", p) for p in new_no_go)]:
            for what, xy in where.items():
                if poly.intersects(shapely.Point(xy)):
                    raise InputError(f"map update: a new {name} polygon covers {what} "
                                     f"({xy[0]:g}, {xy[1]:g}) m; refused")
        m = self.ctx.world.map
        new_map = replace(m, obstacles=(*m.obstacles, *new_obstacles),
                          no_go=(*m.no_go, *new_no_go))
        self.ctx = replace(self.ctx, world=replace(self.ctx.world, map=new_map))
        self._new_batch()
        self._events.append({"map": {"obstacles": [shapely.geometry.mapping(p)
                                                   for p in new_obstacles],
                                     "no_go": [shapely.geometry.mapping(p) for p in new_no_go]}})
        self._map_changed = True
        self._home_reach = None
        self.covered = self.covered.intersection(new_map.free_space)
        if replan:
            self.replan()
        return self.decision()

    # --- persistence ---------------------------------------------------------------------
    def state_dict(self) -> dict:
        """Everything needed to rebuild the session (JSON-serialisable).

        The session is an event log replayed on restore: the initial plan, then in order each
        sample batch, map update and adopted plan. Replans are stored, not recomputed, so a
        restored session is the same whatever planner time limits did.
        """
        return json.loads(json.dumps({
            "version": STATE_VERSION, "scenario": self.ctx.scenario.name,
            "n_vertices": self.n_vertices, "seed": self.seed,
            "replan_margin_J": self.replan_margin_J, "planner_kwargs": self.planner_kwargs,
            "memory_s": self.memory_s, "window_s": self.window_s,
            "plan": self._initial_plan.to_geojson(),
            "events": [{"feed": _records(e["feed"])} if "feed" in e else e
                       for e in self._events],
        }, default=_json_default))

    @classmethod
    def from_state(cls, ctx, state: dict) -> MissionSession:
        """Rebuild a session from ``state_dict()`` (with the context it was made in).

        Raises
        ------
        InputError
            A state of another version or scenario, or a malformed event.
        """
        if not isinstance(state, dict) or state.get("version") != STATE_VERSION:
            raise InputError(f"session state must be a dict of version {STATE_VERSION}")
        if state.get("scenario") != ctx.scenario.name:
            raise InputError(f"session state is for scenario {state.get('scenario')!r}, "
                             f"not {ctx.scenario.name!r}")
        session = cls(ctx, plan_from_geojson(state["plan"]), n_vertices=state["n_vertices"],
                      seed=state["seed"], replan_margin_J=state["replan_margin_J"],
                      planner_kwargs=state["planner_kwargs"], memory_s=state["memory_s"],
                      window_s=state["window_s"])
        for event in state["events"]:
            if "feed" in event:
                session.feed(pd.DataFrame(event["feed"]))
            elif "map" in event:
                session.update_map(event["map"]["obstacles"], event["map"]["no_go"],
                                   replan=False)
            elif "plan" in event:
                plan = plan_from_geojson(event["plan"])
                session._events.append({"plan": event["plan"]})
                session._adopt(plan)
            else:
                raise InputError(f"session state: unknown event {sorted(event)}")
        return session


# --- helpers ------------------------------------------------------------------------------


def plan_from_geojson(data: dict) -> Plan:
    """A Plan from its SPEC §4 GeoJSON (``Plan.to_geojson``).

    Raises
    ------
    InputError
        No tour feature, or per-vertex arrays of the wrong length.
    """
    features = data.get("features", []) if isinstance(data, dict) else []
    tour = next((f for f in features if f.get("properties", {}).get("kind") == "tour"), None)
    if tour is None:
        raise InputError("plan: no feature with kind = 'tour'")
    props = tour["properties"]
    xy = np.asarray(tour["geometry"]["coordinates"], float).reshape(-1, 2)
    arrays = {}
    for key in ("t_s", "speed_mps", "energy_used_J", "energy_to_home_J", "reserve_J",
                "margin_J"):
        values = np.asarray(props.get(key, np.zeros(len(xy))), float)
        if values.shape != (len(xy),):
            raise InputError(f"plan: tour {key} has {values.size} values for {len(xy)} vertices")
        arrays[key] = values
    waypoints = [f["geometry"]["coordinates"] for f in features
                 if f.get("properties", {}).get("kind") == "waypoint"]
    covered = next((shape(f["geometry"]) for f in features
                    if f.get("properties", {}).get("kind") == "covered"), None)
    return Plan(xy, waypoints_xy_m=np.asarray(waypoints, float).reshape(-1, 2), covered=covered,
                summary=dict(data.get("summary", {})), **arrays)


def _distance_to_segments(p, a, b) -> np.ndarray:
    ab = b - a
    length2 = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.where(length2 > 0, length2, 1.0), 0, 1)
    return np.hypot(*(p - (a + t[:, None] * ab)).T)


def _probability(slack_J: float, sd_J: float) -> float:
    if sd_J > 0:
        return float(norm.cdf(slack_J / sd_J))
    return 1.0 if slack_J >= 0 else 0.0


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
