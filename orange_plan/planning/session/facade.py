"""``MissionSession``: the mission in progress, joining the intake of telemetry, the return
home, the plan's checks, the homing decision, replans, map updates and the event log.

The rule it applies is in ``planning.session``'s docstring; the pieces it joins are
``intake`` (samples checked and taken in), ``decision`` (a pure function of the figures) and
``events`` (the log a session is rebuilt from).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import shapely
from scipy.spatial import cKDTree

from orange_plan.errors import InputError
from orange_plan.identify.online import WINDOW_PARTS
from orange_plan.physics.pathcost import path_energy
from orange_plan.planning.paths import cut_path, distinct_vertices
from orange_plan.planning.plan import Plan, StartState, plan_from_geojson
from orange_plan.planning.reach import prepare_reach, way_home
from orange_plan.planning.reserve import closed_loop_return_spread, reserve_from
from orange_plan.planning.session.decision import Decision, Home, HomingState, decide
from orange_plan.planning.session.events import EventLog, check_state, replay_events
from orange_plan.planning.session.intake import Intake, validated_batch
from orange_plan.world.geomap import keep_out_polygon

HOMEWARD_CUTS = 8
"""Even cuts of the stretch ahead: each is checked by the look-ahead of a closed loop's live
check (``MissionSession._lookahead_J``), and the longest that fits is the last piece of route
flown before the way home (``MissionSession.homeward_xy_m``) [-]."""


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
    closed_loop : fly any plan as a closed loop (a route that need not keep a margin at its
        vertices, e.g. a whole lawnmower: the live check alone turns it home); by default
        only a plan with a continuation is

    Attributes
    ----------
    plan : the current plan
    route_xy_m, route_speed_mps : what the robot flies: the plan's tour, or with a
        continuation (a plan that follows a sweep) the tour to its turn point and then the
        continuation (``Plan.closed_loop_route``) [m], [m/s]
    closed_loop : the route goes past the plan's guaranteed extent: the robot turns home on
        the live check (measured energy + the way home + the reserve for the return alone),
        and the rest of the tour's open-loop checks (its margins re-evaluated, the energy per
        metre departing from the plan's) no longer call for replans
    ctx : the current context (its world gains the map updates; each update raises its
        map's ``version``)
    homeward_energy_J : the online model's energy of the route ``homeward_xy_m`` last gave
        (the stretch ahead and the way home from its end, as the decision costs them; NaN
        before it was asked) [J]
    """

    def __init__(self, ctx, plan: Plan | None = None, *, n_vertices: int = 3000, seed: int = 0,
                 replan_margin_J: float | None = None, planner_kwargs: dict | None = None,
                 memory_s: float = 300.0, window_s: float = 300.0,
                 closed_loop: bool = False):
        self._closed_loop_always = bool(closed_loop)
        self.homeward_energy_J = math.nan
        self.closed_loop = self._closed_loop_always  # until a plan is adopted (``_adopt``)
        margin = 0.0 if replan_margin_J is None else float(replan_margin_J)
        if not math.isfinite(margin):
            raise InputError(f"replan_margin_J = {replan_margin_J!r} must be a finite number")
        if not (isinstance(n_vertices, int) and n_vertices >= 10):
            raise InputError(f"n_vertices = {n_vertices!r} must be an integer >= 10")
        self.ctx = ctx
        self.n_vertices, self.seed, self.replan_margin_J = n_vertices, int(seed), margin
        self.planner_kwargs = {"bitstar_legs": 0, **(planner_kwargs or {})}
        self.memory_s, self.window_s = float(memory_s), float(window_s)
        self._log = EventLog()
        self._batch_cache: dict = {}
        self._planner = None
        self._home_reach = None  # (map version, reach, k-d tree of its vertices)
        self._intake = Intake(ctx.model, ctx.scenario.battery.usable_J, memory_s=memory_s,
                              window_s=window_s)
        if plan is None:
            plan = self._plan(StartState())
        self._initial_plan = plan
        self._intake.start_at(plan.xy_m[:1], float(plan.energy_used_J[0]), float(plan.t_s[0]))
        self._adopt(plan)

    # --- state ---------------------------------------------------------------------------
    @property
    def energy_used_J(self) -> float:
        """Measured battery energy so far, sum of P dt from the plan's start energy, never
        below 0 (``intake.energy_used_after``) [J]."""
        return self._intake.energy_used_J

    @property
    def position_xy_m(self) -> tuple[float, float]:
        return self._intake.position_xy_m

    @property
    def trail_xy_m(self) -> np.ndarray:
        """Reported positions, the plan's start first (n, 2) [m]."""
        return self._intake.trail_xy_m

    @property
    def covered(self):
        """Area sensed so far (sensor footprint along the trail)."""
        return self._intake.covered

    @property
    def time_s(self) -> float:
        """Time of the last sample (the plan's start before any) [s]."""
        return self._intake.time_s

    @property
    def _soc(self):
        return self._intake.soc

    @property
    def _events(self) -> EventLog:
        return self._log

    @property
    def energy_available_J(self) -> float:
        """Usable energy counted on [J]: the scenario's, or the smaller capacity the
        telemetry's state of charge shows (``capacity_from_soc``): an aged battery must not
        be spent as if it were new. A closed loop counts on the low estimate
        (``SocCapacity.usable_low_J``: the line's slope known to a gauge step over the fall
        seen), since it spends the battery to the margin."""
        claimed = float(self.ctx.scenario.battery.usable_J)
        soc = self._intake.soc
        # a closed loop spends to the last joules: it counts on the gauge's low estimate
        shown = soc.usable_low_J() if self.closed_loop else soc.usable_J()
        return claimed if shown is None else min(claimed, shown)

    @property
    def capacity_shortfall_J(self) -> float:
        """Scenario usable energy minus the energy counted on [J] (>= 0)."""
        return float(self.ctx.scenario.battery.usable_J) - self.energy_available_J

    @property
    def map_version(self) -> int:
        """The current map's version (0: the scenario's map; +1 per update)."""
        return self.ctx.world.map.version

    @property
    def online_model(self):
        """The scenario model with the estimator's coefficients and covariance."""
        def build():
            est = self._intake.estimator
            return self.ctx.model.with_theta(dict(zip(self.ctx.model.names, est.theta_)),
                                             est.cov_)
        return self._per_batch("online_model", build)

    @property
    def conditions_now(self):
        """The context's conditions with the wind measured over the window (the scenario's
        wind where the samples carry none)."""
        def build():
            window = self._intake.window
            duration = sum(b.duration_s for b in window)
            if duration <= 0:
                return self.ctx.conditions
            wx = sum(b.wind_dt_m[0] for b in window)
            wy = sum(b.wind_dt_m[1] for b in window)
            return self.ctx.conditions.with_wind((wx / duration, wy / duration))
        return self._per_batch("conditions_now", build)

    def _estimate(self):
        """The online estimator's figures after the last batch."""
        return self._per_batch("estimate", self._intake.estimator.estimate)

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
        # with a continuation the robot flies on past the guaranteed extent, turning home
        # on the live check alone (the rest of the tour is not what it flies)
        self.route_xy_m, self.route_speed_mps, self._turn_index = plan.closed_loop_route()
        self.closed_loop = self._closed_loop_always or (
            plan.continuation_xy_m is not None and self._turn_index < len(self.route_xy_m) - 1)
        self._plan_model = self.online_model
        self._plan_conditions = self.conditions_now
        self._plan_map_version = self.map_version
        self._progress = 0
        for b in self._intake.window:
            b.planned_J = None  # a new plan model: predict again

    def adopt_stored_plan(self, geojson: dict) -> None:
        """Fly a plan stored in the event log (a restored session's replan)."""
        plan = plan_from_geojson(geojson)
        self._log.plan(geojson)
        self._adopt(plan)

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
            a negative time, time not increasing (within the batch or against the previous
            batch), a position off the map (``world.positions.check_on_map``). A position on
            the map but outside its free space is taken, and the decision flags it.
        """
        frame = validated_batch(samples, self.ctx.world, self._intake.t_last)
        self._new_batch()
        if self._intake.take(frame, self.ctx):  # a glitch must not move the progress on
            self._progress = self._tour_progress()
        self._log.feed(frame)
        return self.decision()

    def _tour_progress(self) -> int:
        """Index of the tour segment the robot is on: the first one, from the last progress
        on, within half a footprint of the nearest (a tour may pass a place twice)."""
        xy = self.route_xy_m
        if len(xy) < 2:
            return 0
        a, b = xy[self._progress:-1], xy[self._progress + 1:]
        d = _distance_to_segments(np.asarray(self.position_xy_m), a, b)
        near = d <= d.min() + 0.5 * self.ctx.scenario.mission.sensor_radius_m
        return self._progress + int(np.argmax(near))

    # --- decision ------------------------------------------------------------------------
    def decision(self) -> Decision:
        """The decision now (``planning.session``: decision rule; ``decision.decide``)."""
        return decide(self.homing_state())

    def homing_state(self) -> HomingState:
        """The figures the decision weighs, from the telemetry, the return home and the
        plan's checks."""
        used, avail = self.energy_used_J, self.energy_available_J
        where = self._position_where()
        free = where == "free"
        home = self._return_home() if free else None
        return HomingState(
            position_xy_m=self.position_xy_m, time_s=self.time_s, energy_used_J=used,
            energy_available_J=avail, covered_m2=float(self.covered.area),
            position_where=where, reserve=reserve_from(self.ctx.scenario),
            home=home,
            energy_per_m_J=self._energy_per_m_J(),
            map_changed=self.map_version != self._plan_map_version,
            # in closed loop the live check decides when to turn: the open-loop checks of
            # the rest of the tour would call for a replan wherever it spends the reserve
            departure=self._departure() if free and not self.closed_loop else None,
            tour_margin_J=(self._remaining_tour_margin_J(used, avail)
                           if free and not self.closed_loop else math.nan),
            replan_margin_J=self.replan_margin_J,
            lookahead_J=self._lookahead_J(home) if free and self.closed_loop else 0.0)

    def _lookahead_J(self, home: Home) -> float:
        """Closed loop: what the next decision comes too late for [J]. The robot flies on
        for about one more batch before it can hear the next decision, along the stretch of
        route the decision looks at (``_route_ahead``). At each of the stretch's cuts
        (``_stretch_cuts``) it needs the stretch's energy so far, the way home from there and
        the return reserve for both (``_homeward_need_J``); the look-ahead is the most any cut
        needs beyond what the way home needs now, and never less than the last batch drew (a
        stretch costed short, a stop or a slow piece, still leaves the batch's draw). A hill
        just ahead is thus paid for before it is climbed, a hill top past which the way home
        is shorter is not charged as if the robot had to come back down the same way, and a
        cut the end of the stretch would hide (over a crest, round a lane end) is checked
        too. At the route's end: what the last batch drew."""
        last = self._intake.last_batch_J
        ahead = self._route_ahead() if math.isfinite(home.energy_J) else None
        if ahead is None:
            return last
        xy, speeds = ahead
        worst = max(self._homeward_need_J(part, speeds) for part in self._stretch_cuts(xy))
        return max(float(worst) - (home.energy_J + home.reserve_J), last, 0.0)

    @staticmethod
    def _stretch_cuts(xy) -> list[np.ndarray]:
        """The stretch ``xy`` cut at ``HOMEWARD_CUTS`` even fractions of its length, shortest
        first (pieces of fewer than two points left out) [m]."""
        length = float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
        parts = (cut_path(xy, share * length)
                 for share in np.arange(1, HOMEWARD_CUTS + 1) / HOMEWARD_CUTS)
        return [part for part in parts if len(part) >= 2]

    def _route_ahead(self):
        """The stretch of the route the robot flies before the next decision can reach it:
        (polyline from the position, commanded speed of each of its segments) [m], [m/s], or
        None at the route's end. As far as the commanded speed goes in one batch's time (a
        batch spent at a stop does not mean the next one will be), at least a sensor radius."""
        k = self._progress
        rest = np.vstack([self.position_xy_m, self.route_xy_m[k + 1:]])
        keep = distinct_vertices(rest)
        rest, speeds = rest[keep], self.route_speed_mps[k:][keep][:-1]
        if len(rest) < 2:
            return None
        reach_m = self._intake.last_batch_s * float(np.max(speeds[:1], initial=0.0))
        ahead = cut_path(rest, max(reach_m, self.ctx.scenario.mission.sensor_radius_m))
        return (ahead, speeds[:len(ahead) - 1]) if len(ahead) >= 2 else None

    def _stretch_J(self, xy, speeds) -> float:
        """Online-model energy of driving ``xy`` at ``speeds`` under the conditions now [J]."""
        return float(path_energy(self.online_model, self.ctx.world, xy, speeds,
                                 self.conditions_now).total_J)

    def homeward_xy_m(self) -> np.ndarray | None:
        """What a robot told to return home should drive [m]: in closed loop, the route ahead
        as far as the energy left still pays for it, then the way home from its end;
        otherwise (or when none of it fits) ``way_home_xy_m``. None when no way is found.

        The live check turns the robot home while the homing margin still covers the batch
        it would fly before the next decision; what that margin holds is spent on the stretch
        of route the decision looked at (``_route_ahead``): of the stretch's cuts at
        ``HOMEWARD_CUTS`` even fractions, the longest ``s`` with

            E_used + E(stretch to s) + E_home(s) + reserve(E(stretch) + E_home(s)) <= E_avail

        (online model; the reserve is the return reserve of ``_return_home`` with the
        stretch's energy added to the return's and its relative spread applied to it), then
        the way home from ``s``; a cut whose stretch leaves the free space is not taken. The
        route flown after the turn thus keeps the live check's own guarantee at its end,
        where the robot would have been told to turn."""
        ahead = self._route_ahead() if self.closed_loop else None
        if ahead is not None:
            xy, speeds = ahead
            spare = self.energy_available_J - self.energy_used_J
            for part in reversed(self._stretch_cuts(xy)):
                # the stretch starts at the reported position, off the route by the tracking
                # error: its join to the route must keep the map's clearance too
                if not self.ctx.world.segments_free(part[:-1], part[1:]).all():
                    continue
                energy, need = self._homeward_energy_and_need_J(part, speeds)
                if need <= spare:
                    back = self._way_home_from(part[-1])
                    if back is not None:
                        self.homeward_energy_J = energy
                        return np.vstack([part, back[1:]])
        self.homeward_energy_J = self._return_home().energy_J
        return self.way_home_xy_m()

    def _homeward_need_J(self, part, speeds) -> float:
        """Energy a homeward route needs [J]: the stretch ``part`` (from the position, at the
        first of ``speeds``), the way home from its end and the return reserve for both
        (``homeward_xy_m``); inf when no way home is found from its end."""
        return self._homeward_energy_and_need_J(part, speeds)[1]

    def _homeward_energy_and_need_J(self, part, speeds) -> tuple[float, float]:
        """(energy, need) of a homeward route [J]: the online model's energy of the stretch
        ``part`` and of the way home from its end, and that plus the return reserve for both
        (``_homeward_need_J``); (inf, inf) when no way home is found from its end. Built once
        per batch and cut: the look-ahead weighs every cut at each decision, and a robot told
        to turn home asks for the same cuts again (``homeward_xy_m``)."""
        end = part[-1]
        key = f"homeward:{len(part)}:{float(end[0])!r}:{float(end[1])!r}"
        return self._per_batch(key, lambda: self._homeward_energies_J(part, speeds))

    def _homeward_energies_J(self, part, speeds) -> tuple[float, float]:
        """``_homeward_energy_and_need_J`` computed afresh."""
        then = self._return_home(part[-1])
        if not math.isfinite(then.energy_J):
            return math.inf, math.inf
        stretch = self._stretch_J(part, speeds[:len(part) - 1])
        energy = stretch + then.energy_J
        sd = math.hypot(then.sd_J, self._return_relative_spread() * stretch)
        reserve = self._reach()[0].reserve
        return energy, energy + float(reserve.return_only_J(energy, sd**2,
                                                            self.energy_available_J))

    def _position_where(self) -> str:
        """"free" where the map allows the robot to be (``World.is_free``), else
        "off_map" past the boundary or "in_obstacle"."""
        world, (x, y) = self.ctx.world, self.position_xy_m
        if bool(world.is_free(x, y)):
            return "free"
        return "in_obstacle" if world.true_map.boundary.intersects(shapely.Point(x, y)) \
            else "off_map"

    def _departure(self):
        """(measured, plan-model predicted, predictive sd) energy per metre over the window
        [J/m], or None while the window is too short to have a spread."""
        window = self._intake.window
        if len(window) < 2 * WINDOW_PARTS:
            return None
        dist = sum(b.distance_m for b in window)
        if dist <= 0:
            return None
        measured = sum(b.measured_J for b in window) / dist
        # the plan's prediction: its model under its conditions (its wind), on the motion driven
        wx, wy = self._plan_conditions.wind_xy_mps
        for b in window:  # each batch once per plan (a window holds up to ~150)
            if b.planned_J is None:
                b.planned_J = float(np.sum(np.asarray(self._plan_model.power_W(
                    b.state.with_(wind_x_mps=wx, wind_y_mps=wy)), float) * b.dt))
        predicted = sum(b.planned_J for b in window) / dist
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

    def way_home_xy_m(self) -> np.ndarray | None:
        """The way home the decision costs, from the position (the roadmap's best return,
        joined straight) [m]; None when no way is found."""
        return self._way_home_from(self.position_xy_m)

    def _way_home_from(self, xy) -> np.ndarray | None:
        """The roadmap's best return from ``xy`` with the online model [m], or None."""
        reach, tree = self._reach()
        exact = replace(reach.exact, model=self.online_model, world=self.ctx.world,
                        conditions=self.conditions_now)
        return way_home(replace(reach, exact=exact), tuple(float(v) for v in xy), tree)

    def _return_home(self, xy=None) -> Home:
        """Best roadmap return from the position (or ``xy``; free: ``homing_state`` asks only
        then), driven from rest to rest and evaluated with the online model (energy and
        gradient from one drive, as the tour's returns)."""
        from orange_plan.planning.tour import drive

        reach, tree = self._reach()
        model = self.online_model
        exact = replace(reach.exact, model=model, world=self.ctx.world,
                        conditions=self.conditions_now)
        start = self.position_xy_m if xy is None else tuple(float(v) for v in xy)
        back = way_home(replace(reach, exact=exact), start, tree)
        if back is None:
            return Home(math.inf, 0.0, 0.0)
        if len(back) < 2:  # at home
            return Home(0.0, float(reach.reserve.return_only_J(
                0.0, 0.0, self.energy_available_J)), 0.0)
        driven = drive(exact, back, exact.speed_mps)
        energy = float(driven.energy_J[-1])
        var = float(model.energy_variance_J2(driven.gradient[-1]))
        spread = self._return_relative_spread() * energy
        sd = math.sqrt(max(var, 0.0) + spread**2)
        res = float(reach.reserve.return_only_J(energy, sd**2, self.energy_available_J))
        return Home(energy, res, sd)

    def _return_relative_spread(self) -> float:
        """Relative spread taken for the energy of the way home beyond its coefficient part
        [-]: the estimator's own, never below ``_return_spread_floor``."""
        return max(self._relative_spread(), self._return_spread_floor())

    def _return_spread_floor(self) -> float:
        """Least relative spread of the way home's energy a closed loop assumes [-]: the
        estimator learns the run on the way out, but the way back crosses other ground in
        other headings; ``RETURN_SPREAD_FLOOR`` of the model's run-to-run discrepancy (0
        for an open-loop plan, whose own reserve covers the whole trip)."""
        if not self.closed_loop:
            return 0.0
        return closed_loop_return_spread(self.ctx.model)

    def _relative_spread(self) -> float:
        """The online estimator's predictive sd of the energy per metre over its value
        (conditions: gusts, terrain, stops) [-]; 0 before it can say."""
        est = self._estimate()
        e, sd = est.energy_per_m_J, est.energy_per_m_sd_J
        return float(sd / e) if (math.isfinite(e) and e > 0 and math.isfinite(sd)) else 0.0

    def _reach(self):
        """Roadmap and to-home field of the current world, and a k-d tree of its vertices
        (built once per map version)."""
        if self._home_reach is None or self._home_reach[0] != self.map_version:
            reach = prepare_reach(self.ctx, None, 0.0, n_vertices=self.n_vertices,
                                  seed=self.seed, with_gradient=False)
            self._home_reach = (self.map_version, reach, cKDTree(reach.roadmap.xy_m))
        return self._home_reach[1:]

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
        res = reserve_from(self.ctx.scenario).rescaled_J(plan.reserve_J[idx], ratio)
        return float(np.min(avail - used - online - to_home - res))

    # --- replanning ----------------------------------------------------------------------
    def replan(self) -> Plan:
        """A new tour from the current position, energy, time and covered area, with the
        online model and the current world; it becomes the session's plan.

        Raises
        ------
        InputError
            When no tour fits (e.g. the robot should go home: the battery left cannot visit
            anything new and come back), or the position is not in the map's free space.
        """
        # a battery smaller than the scenario's is planned as that much energy already spent
        start = StartState(self.position_xy_m, self.energy_used_J + self.capacity_shortfall_J,
                           self.time_s, None if self.covered.is_empty else self.covered)
        plan = self._plan(start)
        self._log.plan(plan.to_geojson())
        self._adopt(plan)
        return plan

    def _plan(self, start: StartState) -> Plan:
        """A tour with the online model and the current world. The first plan builds the
        roadmap and candidate legs; later replans reuse them (``tour.TourPlanner``: a warm
        replan only adds the robot's position to the roadmap), unless the map's version
        changed."""
        from orange_plan.planning.tour import TourPlanner

        if self._planner is None:
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
            or outside the boundary), or that covers the robot's position or home or comes
            closer to them than the robot's keep-away
            (``robot.radius_m + mission.clearance_m``) (one line, naming which polygon or
            the distance).
        """
        boundary = self.ctx.world.true_map.boundary  # a map file's rules (world.geomap)
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
        m = self.ctx.world.true_map
        new_map = replace(m, obstacles=(*m.obstacles, *new_obstacles),
                          no_go=(*m.no_go, *new_no_go), version=m.version + 1)
        world = self.ctx.world.with_map(new_map)  # inflated by the robot's keep-away
        for what, xy in where.items():  # refused only when this update brings the edge close
            problem = world.clearance_problem(xy)
            if problem and self.ctx.world.clearance_problem(xy) is None:
                raise InputError(f"map update refused: {what} {problem}")
        self.ctx = replace(self.ctx, world=world)
        self._new_batch()
        self._log.map_update(new_obstacles, new_no_go)
        self._intake.covered = self._intake.covered.intersection(new_map.free_space)
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
        return self._log.state({
            "scenario": self.ctx.scenario.name,
            "n_vertices": self.n_vertices, "seed": self.seed,
            "replan_margin_J": self.replan_margin_J, "planner_kwargs": self.planner_kwargs,
            "memory_s": self.memory_s, "window_s": self.window_s,
            "closed_loop": self._closed_loop_always}, self._initial_plan)

    @classmethod
    def from_state(cls, ctx, state: dict) -> MissionSession:
        """Rebuild a session from ``state_dict()`` (with the context it was made in).

        Raises
        ------
        InputError
            A state of another version or scenario, or a malformed event.
        """
        check_state(state, ctx.scenario.name)
        session = cls(ctx, plan_from_geojson(state["plan"]), n_vertices=state["n_vertices"],
                      seed=state["seed"], replan_margin_J=state["replan_margin_J"],
                      planner_kwargs=state["planner_kwargs"], memory_s=state["memory_s"],
                      window_s=state["window_s"], closed_loop=state.get("closed_loop", False))
        replay_events(session, state["events"])
        return session


# --- helpers ------------------------------------------------------------------------------


def _distance_to_segments(p, a, b) -> np.ndarray:
    ab = b - a
    length2 = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.where(length2 > 0, length2, 1.0), 0, 1)
    return np.hypot(*(p - (a + t[:, None] * ab)).T)
