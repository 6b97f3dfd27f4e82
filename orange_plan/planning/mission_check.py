"""Does a mission fit the battery? Energy, time and homing margin of a mission as flown.

Problem statement (kept apart from how it is solved): a mission (``export.missions_in``:
home, waypoints with altitude, speed, hold time and corner radius, a take-off altitude, the
way home at the end) is flown by the scenario's robot under the scenario's conditions (or a
given wind). Report, per leg and in total, the battery energy and time with the predictive
standard deviation of the energy; at the end of every leg the energy used so far, the energy of
the mission's own way home from there (RTL: a straight leg home at the leg's altitude, then
the landing) and the homing margin

    margin = E_avail - E_used - E_home - reserve(E_used + E_home)

with the scenario's reserve rule (``planning.reserve``); the verdict (``fits``: every margin
>= 0; ``fits_without_reserve``: every margin + reserve >= 0; else ``does_not_fit``) with the
first waypoint where it fails; and the point of no return, the last point along the route up
to which the margin is still >= 0.

How it is solved:

1. Stages (``planning.mission_stages``): [take-off], one 3-D straight leg per pair of
   waypoints, [the way home], [landing], each at its commanded or default speed within the
   robot's limits, and the speed allowed through each corner.
2. Motion (``planning.mission_motion``): the profile of ``physics.profile.Driver`` between
   stops, slowing for each corner's arc.
3. Energy: the scenario's energy model on the motion samples, a hold being samples at rest;
   the variance is the model's predictive variance (``predictive_variance_J2``) of the
   gradient summed over the samples.
4. The point of no return is found on the margin taken as linear in the distance flown
   between consecutive leg ends.


Why the verdict is safe: every leg's energy is that of the motion the robot must fly (stops,
ramps, corner slow-downs, holds, climbs), never the cruise figure; the way home from every
leg end is flown and charged in full, landing included, and the reserve is sized by the same
rule as every plan's. A ``fits`` verdict is only as good as the model: its standard deviation
is reported with every figure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from orange_plan.errors import InputError
from orange_plan.export.missions_in import Mission, MissionWaypoint
from orange_plan.limits import (
    MAX_MISSION_HOME_SAMPLES,
    MAX_MISSION_SAMPLES,
    MAX_MISSION_WAYPOINTS,
)
from orange_plan.physics.pathcost import max_step_m
from orange_plan.physics.profile import SAMPLE_DT_S
from orange_plan.planning.mission_motion import FlatWorld, Samples, drive, energy_totals
from orange_plan.planning.mission_stages import (
    Stage,
    mission_stages,
    robot_limits,
    way_home,
    with_corners,
)
from orange_plan.planning.reserve import reserve_from
from orange_plan.world.positions import check_on_map

__all__ = ["LegCheck", "Mission", "MissionCheck", "MissionWaypoint", "check_mission",
           "mission_samples"]

VERDICTS = ("fits", "fits_without_reserve", "does_not_fit")
HOME_BATCH_SAMPLES = 500_000
"""Samples of ways home driven at once (bounds the memory of a long mission's check)."""
WIND_SWEEP_DEG = 10.0
"""Step of the worst-wind-direction sweep [deg]."""


# --- the answer -------------------------------------------------------------------------------


@dataclass(frozen=True)
class LegCheck:
    """One stage of the mission as flown (energies [J], times [s], lengths [m]).

    Attributes
    ----------
    kind : ``takeoff``, ``leg``, ``return`` (the way home added after the last waypoint) or
        ``landing``
    from_waypoint, to_waypoint : waypoint indices (0: home)
    length_m : 3-D length; climb_m : rise (negative: descent); speed_mps : commanded speed
    energy_J, energy_sd_J : energy of the stage (hold at its end included) and its predictive sd
    duration_s : its time; distance_m : distance along the route at its end
    from_xyz_m, to_xyz_m : where it starts and ends (map frame, z above home) [m]
    energy_used_J : energy used at its end; energy_to_home_J : energy of the way home from
        there; reserve_J : the reserve for both; margin_J : the homing margin there
    """

    kind: str
    from_waypoint: int
    to_waypoint: int
    length_m: float
    climb_m: float
    speed_mps: float
    energy_J: float
    energy_sd_J: float
    duration_s: float
    distance_m: float
    energy_used_J: float
    energy_to_home_J: float
    reserve_J: float
    margin_J: float
    from_xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    to_xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def as_dict(self) -> dict:
        return {"kind": self.kind, "from": self.from_waypoint, "to": self.to_waypoint,
                **{k: getattr(self, k) for k in (
                    "length_m", "climb_m", "speed_mps", "energy_J", "energy_sd_J",
                    "duration_s", "distance_m", "energy_used_J", "energy_to_home_J",
                    "reserve_J", "margin_J")},
                "from_xyz_m": list(self.from_xyz_m), "to_xyz_m": list(self.to_xyz_m)}


@dataclass(frozen=True)
class MissionCheck:
    """The check of a whole mission (module docstring).

    Attributes
    ----------
    legs : the stages in flight order
    energy_J, energy_sd_J, duration_s : the whole mission, take-off to landing
    energy_available_J : usable battery energy; reserve_J : the reserve for the whole mission
    verdict : one of ``VERDICTS``
    first_failing_waypoint : the waypoint at the end of the first leg whose margin is negative
        (reserve included for ``fits_without_reserve``, left out for ``does_not_fit``); None
        when it fits
    point_of_no_return : (waypoint index, distance along the route [m]): the last point up to
        which the margin (reserve included) is >= 0, on the leg leaving that waypoint (the end
        of the mission when it fits); None when even the start has no margin
    wind_xy_mps : the wind the mission was checked in
    worst_wind : (from_deg, energy_J) of the direction of the same wind speed that costs the
        most, when asked for
    reserve_rule : the reserve rule in words
    """

    legs: tuple[LegCheck, ...]
    energy_J: float
    energy_sd_J: float
    duration_s: float
    energy_available_J: float
    reserve_J: float
    verdict: str
    first_failing_waypoint: int | None
    point_of_no_return: tuple[int, float] | None
    wind_xy_mps: tuple[float, float]
    worst_wind: tuple[float, float] | None
    reserve_rule: str
    start_margin_J: float = 0.0
    """Margin at home before the take-off (nothing used, nothing to fly home) [J]."""
    warnings: tuple[str, ...] = ()
    """Legs that leave the map's free space (through an obstacle, a no-go zone or out of the
    boundary, within the robot's keep-away): the energy is that of the straight leg."""

    @property
    def margin_J(self) -> np.ndarray:
        """Margin at the end of every stage [J]."""
        return np.array([leg.margin_J for leg in self.legs])

    def as_dict(self) -> dict:
        """The ``--json`` answer (docs/json.md)."""
        pnr = self.point_of_no_return
        return {
            "energy_J": self.energy_J, "energy_sd_J": self.energy_sd_J,
            "duration_s": self.duration_s, "energy_available_J": self.energy_available_J,
            "reserve_J": self.reserve_J, "reserve_rule": self.reserve_rule,
            "verdict": self.verdict, "first_failing_waypoint": self.first_failing_waypoint,
            "point_of_no_return": None if pnr is None else {"waypoint": pnr[0],
                                                            "distance_m": pnr[1]},
            "wind_xy_mps": list(self.wind_xy_mps), "warnings": list(self.warnings),
            "worst_wind": None if self.worst_wind is None else {
                "from_deg": self.worst_wind[0], "energy_J": self.worst_wind[1]},
            "legs": [leg.as_dict() for leg in self.legs],
        }


# --- the check --------------------------------------------------------------------------------


def _context(scenario):
    """A Context from a Context or a Scenario."""
    if hasattr(scenario, "world") and hasattr(scenario, "model"):
        return scenario
    from orange_plan.context import context_of

    return context_of(scenario)


def _ground_above_home(world, mission: Mission):
    """``ground(x, y)``: the height of the world's ground above home's [m] (0 on flat
    ground)."""
    home = mission.waypoints[0]
    home_z = float(world.elevation_at(home.x_m, home.y_m))
    return lambda x, y: np.asarray(world.elevation_at(x, y), float) - home_z


def _placed(mission: Mission, world, aerial: bool, in_map_frame: bool):
    """The mission with every altitude above home (terrain-relative ones placed on the
    world's ground), the ground function, and the warnings of a local frame.

    In the map frame a mission off the map, or an aerial one with a waypoint below the ground
    there, is refused; a waypoint below home is fine above the ground (a valley surveyed from
    a ridge). In a local frame (no origin) the terrain is unknown: a waypoint below home is
    said, not refused."""
    if in_map_frame:
        check_on_map(world, mission.xyz_m[:, 0], mission.xyz_m[:, 1], mission.source,
                     "waypoint")
    ground_m = _ground_above_home(world, mission)
    mission = mission.above_home(ground_m)
    if not aerial:
        return mission, ground_m, ()
    xyz = mission.xyz_m
    if not in_map_frame:
        below = int(np.sum(xyz[1:, 2] < 0))
        return mission, ground_m, (f"{below} waypoint(s) below home: without the map's "
                                   "origin nothing checks them against the ground",) \
            if below else ()
    ground = ground_m(xyz[:, 0], xyz[:, 1])
    low = np.flatnonzero(xyz[1:, 2] < ground[1:] - 1e-6)
    if low.size:
        i = int(low[0]) + 1
        raise InputError(f"{mission.source}: waypoint {i} at {xyz[i, 2]:g} m above home is "
                         f"below the ground there ({ground[i]:g} m above home)")
    return mission, ground_m, ()


def _flight(mission: Mission, ctx, in_map_frame: bool, duty: float):
    """What checking and sampling a mission share: (mission above home, world, robot,
    stages with corners, sub-step length [m], the ground's height above home ``ground(x,
    y)`` [m], warnings), its size checked."""
    robot = robot_limits(ctx)
    world = ctx.world if in_map_frame else FlatWorld(ctx.world)
    mission, ground_m, warnings = _placed(mission, world, robot.aerial, in_map_frame)
    step_m = max_step_m(world)
    stages = with_corners(mission_stages(mission, robot, ground_m), mission, robot)
    _check_size(mission, stages, duty, step_m)
    return mission, world, robot, stages, step_m, ground_m, warnings


def _samples_per_m(stages: list[Stage], duty: float, step_m: float) -> float:
    """Upper bound of samples (or sub-steps) per metre of the stages' flight."""
    slowest = min(st.speed for st in stages)
    return max(1.0 / (slowest * SAMPLE_DT_S * duty), 1.0 / step_m)


def _check_size(mission: Mission, stages: list[Stage], duty: float, step_m: float) -> None:
    """Refuse a mission whose own samples would exceed ``MAX_MISSION_SAMPLES``, or whose
    ways home from every leg end would exceed ``MAX_MISSION_HOME_SAMPLES`` (driven in
    batches of ``HOME_BATCH_SAMPLES``)."""
    if len(mission.waypoints) > MAX_MISSION_WAYPOINTS:
        raise InputError(f"{mission.source}: {len(mission.waypoints):,} waypoints, more than "
                         f"the {MAX_MISSION_WAYPOINTS:,} a check takes")
    per_m = _samples_per_m(stages, duty, step_m)
    own = per_m * sum(st.length_m for st in stages)
    home = np.array([mission.waypoints[0].x_m, mission.waypoints[0].y_m, 0.0])
    back = per_m * sum(float(np.abs(np.subtract(st.end, home)).sum()) for st in stages)
    for count, limit, what in ((own, MAX_MISSION_SAMPLES, "flying the mission"),
                               (back, MAX_MISSION_HOME_SAMPLES, "the ways home")):
        if count > limit:
            raise InputError(f"{mission.source}: {what} takes about {count:,.0f} samples of "
                             f"{SAMPLE_DT_S:g} s, more than the {limit:,} a check takes "
                             "(fewer or shorter legs, or a faster speed)")


def check_mission(mission: Mission, scenario, *, wind=None, worst_wind: bool = False,
                  in_map_frame: bool = True) -> MissionCheck:
    """Check a mission against the scenario's battery (module docstring).

    Parameters
    ----------
    mission : the mission in the map frame
    scenario : a ``Context`` (``context.load_context``) or a ``Scenario``
    wind : wind (x east, y north) [m/s] instead of the scenario's
    worst_wind : also sweep the wind's direction (same speed) for the costliest one
    in_map_frame : False for a mission in a local frame at its home (a map without origin):
        flat default ground, no placement check (a waypoint below home is warned of)

    Raises
    ------
    InputError
        A mission off the map or below the terrain, nothing to fly.
    """
    ctx = _context(scenario)
    conditions = ctx.conditions if wind is None else ctx.conditions.with_wind(wind)
    mission, world, robot, stages, step_m, ground_m, warnings = _flight(
        mission, ctx, in_map_frame, conditions.duty_cycle)
    if in_map_frame and robot.aerial:
        warnings += _passing_under_ground(stages, ground_m, step_m)
    n = len(stages)
    samples = drive([(None, stages)], world, robot, conditions, step_m)
    energy, grad, duration = energy_totals(ctx.model, samples, n)
    home_e, home_g = _ways_home(stages, mission, world, robot, conditions, step_m, ctx.model)
    legs, total_reserve = _legs(stages, energy, grad, duration, home_e, home_g, ctx)
    avail = ctx.scenario.battery.usable_J
    verdict, failing = _verdict(legs)
    worst = _worst_wind(ctx.model, samples, conditions, n) if worst_wind else None
    total_g = grad.sum(axis=0)
    total = float(energy.sum())
    rule = reserve_from(ctx.scenario)
    start_margin = float(avail - rule.size_J(0.0, 0.0, avail))
    return MissionCheck(
        tuple(legs), total, float(np.sqrt(ctx.model.predictive_variance_J2(total_g, total))),
        float(duration.sum()), float(avail), total_reserve, verdict, failing,
        _point_of_no_return(legs, start_margin), conditions.wind_xy_mps, worst,
        rule.describe(), start_margin,
        warnings + (_leaving_free_space(stages, ctx.world) if in_map_frame else ()))


MAX_WARNED_LEGS = 5
"""Legs named one by one in a warning about legs (the rest are counted)."""
UNDER_GROUND_M = 1e-3
"""A leg this far below the ground's surface somewhere between its ends passes through it
[m] (round-off of the raster's interpolation is not)."""


def _legs_named(bad: list[Stage], what: str) -> tuple[str, ...]:
    """One warning naming the legs ``bad`` (at most ``MAX_WARNED_LEGS``), or none."""
    if not bad:
        return ()
    named = ", ".join(f"{st.kind} {st.from_wp} -> {st.to_wp}" for st in bad[:MAX_WARNED_LEGS])
    more = f" and {len(bad) - MAX_WARNED_LEGS} more" if len(bad) > MAX_WARNED_LEGS else ""
    return (f"{len(bad)} leg(s) {what}: {named}{more}",)


def _leaving_free_space(stages: list[Stage], world) -> tuple[str, ...]:
    """One warning naming the legs whose straight line leaves the map's free space."""
    flat = [st for st in stages if not st.vertical]
    if not flat:
        return ()
    free = world.segments_free([st.start[:2] for st in flat], [st.end[:2] for st in flat])
    return _legs_named([st for st, ok in zip(flat, free) if not ok],
                       "leave the map's free space (an obstacle, a no-go zone or the boundary, "
                       "within the robot's keep-away)")


def _passing_under_ground(stages: list[Stage], ground_m, step_m: float) -> tuple[str, ...]:
    """One warning naming the legs whose straight line dips below the map's ground between
    its ends (a ridge between two waypoints above the ground), looked at every ``step_m``
    [m] (at most the mission's own samples, which ``_check_size`` bounds)."""
    flat = [st for st in stages if not st.vertical]
    if not flat:
        return ()
    counts = np.array([math.ceil(st.horiz_m / step_m) + 1 for st in flat])
    leg = np.repeat(np.arange(len(flat)), counts)
    frac = np.concatenate([np.linspace(0.0, 1.0, c) for c in counts])
    start = np.array([st.start for st in flat], float)
    delta = np.array([st.end for st in flat], float) - start
    p = start[leg] + frac[:, None] * delta[leg]
    under = p[:, 2] < ground_m(p[:, 0], p[:, 1]) - UNDER_GROUND_M
    return _legs_named([flat[i] for i in np.unique(leg[under])],
                       "pass below the map's ground between their waypoints (the energy is "
                       "that of the straight leg)")


def mission_samples(mission: Mission, scenario, *, in_map_frame: bool = True):
    """Motion samples of the mission as ``check_mission`` flies it (take-off to landing, no
    way home), and the time each stands for: ``(MotionState, weight_s)``.

    The motion does not depend on the model's coefficients, so one set of samples prices the
    mission under many models: ``sum(model.power_W(state) * weight_s)`` is ``check_mission``'s
    ``energy_J`` under that model (a cross-validation refits the model per fold).
    """
    ctx = _context(scenario)
    _, world, robot, stages, step_m, _, _ = _flight(mission, ctx, in_map_frame,
                                                    ctx.conditions.duty_cycle)
    samples = drive([(None, stages)], world, robot, ctx.conditions, step_m)
    return samples.state, samples.weight_s


def _ways_home(stages, mission, world, robot, conditions, step_m, model):
    """Energy [J] and gradient of the way home from each stage's end (``way_home``: at the
    speed leaving the last waypoint, the mission's own return, or cruise); 0 once home and
    landed, or at the end of a mission that ends away from home."""
    home = (mission.waypoints[0].x_m, mission.waypoints[0].y_m)
    return_speed = mission.waypoints[-1].speed_mps  # the mission's own return (None: cruise)
    groups = []
    for k, st in enumerate(stages[:-1]):  # from the end of the mission nothing is left to fly
        way = way_home(st.end, home, st.to_wp, return_speed, robot)
        if way:
            groups.append((k, way))
    energy, grad = np.zeros(len(stages)), np.zeros((len(stages), len(model.theta)))
    for batch in _batches(groups, _samples_per_m(stages, conditions.duty_cycle, step_m)):
        samples = drive(batch, world, robot, conditions, step_m)
        e, g, _ = energy_totals(model, samples, len(stages))
        energy, grad = energy + e, grad + g
    return energy, grad


def _batches(groups, per_m: float):
    """``groups`` cut into batches of about ``HOME_BATCH_SAMPLES`` samples (memory bound)."""
    batch, count = [], 0.0
    for group in groups:
        batch.append(group)
        count += per_m * sum(st.length_m for st in group[1])
        if count >= HOME_BATCH_SAMPLES:
            yield batch
            batch, count = [], 0.0
    if batch:
        yield batch


def _legs(stages, energy, grad, duration, home_e, home_g, ctx):
    """Per-stage table with cumulative energy, way home, reserve and margin."""
    model, avail = ctx.model, ctx.scenario.battery.usable_J
    rule = reserve_from(ctx.scenario)
    used = np.cumsum(energy)
    used_g = np.cumsum(grad, axis=0)
    need = used + home_e
    var = model.predictive_variance_J2(used_g + home_g, need)
    reserve = rule.size_J(need, var, avail)
    margin = avail - need - reserve
    sd = np.sqrt(model.predictive_variance_J2(grad, energy))
    distance = np.cumsum([st.length_m for st in stages])
    legs = [LegCheck(st.kind, st.from_wp, st.to_wp, st.length_m,
                     float(st.end[2] - st.start[2]), st.speed, float(energy[k]), float(sd[k]),
                     float(duration[k]), float(distance[k]), float(used[k]), float(home_e[k]),
                     float(reserve[k]), float(margin[k]),
                     tuple(float(v) for v in st.start), tuple(float(v) for v in st.end))
            for k, st in enumerate(stages)]
    total_var = model.predictive_variance_J2(used_g[-1], used[-1])
    return legs, float(rule.size_J(used[-1], total_var, avail))


def _verdict(legs) -> tuple[str, int | None]:
    margin = np.array([leg.margin_J for leg in legs])
    bare = margin + np.array([leg.reserve_J for leg in legs])
    if np.all(margin >= 0):
        return "fits", None
    if np.all(bare >= 0):
        return "fits_without_reserve", legs[int(np.flatnonzero(margin < 0)[0])].to_waypoint
    return "does_not_fit", legs[int(np.flatnonzero(bare < 0)[0])].to_waypoint


def _point_of_no_return(legs, start_margin_J: float) -> tuple[int, float] | None:
    """(waypoint, distance [m]) where the margin, linear in distance between leg ends, first
    turns negative; the mission's end when it never does; None when negative at the start."""
    if start_margin_J < 0:
        return None
    prev_m, prev_d = start_margin_J, 0.0
    for leg in legs:
        if leg.margin_J < 0:
            frac = prev_m / (prev_m - leg.margin_J)
            return leg.from_waypoint, prev_d + frac * (leg.distance_m - prev_d)
        prev_m, prev_d = leg.margin_J, leg.distance_m
    return legs[-1].to_waypoint, legs[-1].distance_m


def _worst_wind(model, samples: Samples, conditions, n: int) -> tuple[float, float]:
    """(from_deg, energy_J) of the costliest direction of the checked wind's speed."""
    from orange_plan.physics.wind import wind_xy_mps

    speed = float(np.hypot(*conditions.wind_xy_mps))
    best = (0.0, -math.inf)
    for from_deg in np.arange(0.0, 360.0, WIND_SWEEP_DEG):
        wx, wy = wind_xy_mps(speed, float(from_deg))
        size = samples.label.size
        state = samples.state.with_(wind_x_mps=np.full(size, wx), wind_y_mps=np.full(size, wy))
        power = np.broadcast_to(np.asarray(model.power_W(state), float), (size,))
        energy = float(np.sum(power * samples.weight_s))
        if energy > best[1]:
            best = (float(from_deg), energy)
    return best
