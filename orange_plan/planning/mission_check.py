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

1. Stages: [take-off: a vertical climb at home], one leg per pair of waypoints (a 3-D straight
   line; aerial robots fly the waypoints' altitudes, ground and marine robots the map's
   terrain, which gives their grade), [the way home], [landing: a vertical descent]. A leg
   without a speed takes the robot's default for its kind: cruise (``Context.cruise_speed_mps``)
   for a leg that moves sideways, ``robot.climb_mps`` / ``robot.descent_mps`` for a vertical
   one, ``robot.landing_mps`` (default: the descent speed) for the final landing (an
   autopilot's automatic landing descends slower than its mission legs: about 1 m/s against
   up to 4 m/s on a DJI Matrice 100); every leg's speed is capped so that its vertical rate
   stays within those speeds and its speed within ``robot.v_max_mps``.
2. Motion: the robot stops at a hold, before and after a vertical stage, at the end, and at a
   waypoint without corner radius ("normal" missions). Between stops it drives the
   profile of ``physics.profile.Driver`` (the planner's and the simulator's): acceleration and
   braking at ``accel_max_mps2``, duty-cycle stops, at rest at both ends. At a waypoint with
   corner radius r it turns on the arc tangent to both legs that starts r before it; that
   arc has radius ``R = r / tan(theta / 2)`` for a heading change theta, and the robot slows to
   ``v = sqrt(accel_max R)`` (lateral acceleration at most ``accel_max``) by then, braking at
   ``accel_max``. The arc's length replaces the polyline's ``2 r`` around the waypoint
   (``_round_corners``: 21 % shorter at 90 degrees; a survey of 40 m legs on 20 m radii is
   mostly arcs).
3. Energy: the scenario's energy model (``EnergyModel.power_W``) on the motion samples
   (speed, acceleration, grade, heading, wind, yaw rate), a hold being samples at rest, so any
   term the model has (a calibrated one included) counts; the variance is the model's
   predictive variance (``predictive_variance_J2``) of the gradient summed over the samples.
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
from dataclasses import dataclass, replace

import numpy as np

from orange_plan.errors import InputError, OrangeError
from orange_plan.export.missions_in import Mission, MissionWaypoint
from orange_plan.limits import (
    MAX_MISSION_HOME_SAMPLES,
    MAX_MISSION_SAMPLES,
    MAX_MISSION_WAYPOINTS,
)
from orange_plan.physics.pathcost import Steps, max_step_m, subdivide
from orange_plan.physics.profile import (
    CREEP_FRACTION,
    SAMPLE_DT_S,
    STOP_EVERY_S,
    TURN_SPREAD_S,
    Driver,
    drive_state,
    spread_yaw_rate,
)
from orange_plan.physics.state import MotionState
from orange_plan.planning.reserve import reserve_from
from orange_plan.world.positions import check_on_map

__all__ = ["LegCheck", "Mission", "MissionCheck", "MissionWaypoint", "check_mission",
           "mission_samples"]

DEFAULT_CLIMB_MPS = 2.5
"""Default vertical climb speed of an aerial robot without ``robot.climb_mps`` [m/s]
(ArduPilot's WPNAV_SPEED_UP default)."""
DEFAULT_DESCENT_MPS = 1.5
"""Default vertical descent speed of an aerial robot without ``robot.descent_mps`` [m/s]
(ArduPilot's WPNAV_SPEED_DN default)."""
AT_HOME_M = 1e-3
"""A point this close to home (horizontally) is home: no way home to fly from it [m] (a
waypoint read from latitude/longitude lands within round-off of it)."""
VERTICAL_EPS_M = 1e-6
"""A stage whose horizontal length is below this is vertical [m]."""
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


# --- stages -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Stage:
    """A straight piece of the flight: start and end (x, y, z) [m], cruise speed [m/s], hold
    time at the end [s] and the speed allowed through the end (0: a stop) with the distance
    before and after the end over which it holds (the corner's arc) [m]."""

    kind: str
    from_wp: int
    to_wp: int
    start: tuple
    end: tuple
    speed: float
    hold_s: float = 0.0
    hold_start_s: float = 0.0
    corner_mps: float = 0.0
    corner_r_m: float = 0.0

    @property
    def delta(self) -> np.ndarray:
        return np.subtract(self.end, self.start)

    @property
    def horiz_m(self) -> float:
        return float(np.hypot(*self.delta[:2]))

    @property
    def vertical(self) -> bool:
        return self.horiz_m < VERTICAL_EPS_M

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(self.delta))


@dataclass(frozen=True)
class _Robot:
    """What the stages need from the scenario."""

    aerial: bool
    cruise_mps: float
    climb_mps: float
    descent_mps: float
    v_max_mps: float
    accel_mps2: float
    landing_mps: float


def _robot(ctx) -> _Robot:
    r = ctx.scenario.robot
    climb = getattr(r, "climb_mps", None) or min(DEFAULT_CLIMB_MPS, r.v_max_mps)
    descent = getattr(r, "descent_mps", None) or min(DEFAULT_DESCENT_MPS, r.v_max_mps)
    landing = getattr(r, "landing_mps", None) or descent
    return _Robot(r.kind == "aerial", min(ctx.cruise_speed_mps, r.v_max_mps), climb, descent,
                  r.v_max_mps, r.accel_max_mps2, landing)


def _leg_speed(robot: _Robot, wanted, start, end) -> float:
    """Commanded speed of a straight stage, capped by v_max and the vertical speeds [m/s]."""
    d = np.subtract(end, start)
    length, rise = float(np.linalg.norm(d)), float(d[2])
    vertical = float(np.hypot(*d[:2])) < VERTICAL_EPS_M
    if wanted is None:
        wanted = (robot.climb_mps if rise > 0 else robot.descent_mps) if vertical \
            else robot.cruise_mps
    speed = min(float(wanted), robot.v_max_mps)
    if length > 0 and rise != 0:
        limit = robot.climb_mps if rise > 0 else robot.descent_mps
        speed = min(speed, limit * length / abs(rise))
    return speed


def _stages(mission: Mission, robot: _Robot) -> list[_Stage]:
    """The flight as stages, corners not yet set (module docstring, step 1)."""
    wps = mission.waypoints
    z = [w.z_m if robot.aerial else 0.0 for w in wps]
    home = (wps[0].x_m, wps[0].y_m)
    takeoff = (mission.takeoff_alt_m if mission.takeoff_alt_m is not None else z[0]) \
        if robot.aerial else 0.0
    stages = []
    here = (*home, takeoff)
    waiting_s = wps[0].stay_s  # a hold at home before anything flies
    if takeoff > 0:
        stages.append(_Stage("takeoff", 0, 0, (*home, 0.0), here,
                             _leg_speed(robot, None, (*home, 0.0), here), waiting_s))
        waiting_s = 0.0
    for i in range(len(wps) - 1):
        end = (wps[i + 1].x_m, wps[i + 1].y_m, z[i + 1])
        if np.linalg.norm(np.subtract(end, here)) == 0:  # a repeated waypoint: only its hold
            if stages:
                stages[-1] = replace(stages[-1], hold_s=stages[-1].hold_s + wps[i + 1].stay_s)
            else:
                waiting_s += wps[i + 1].stay_s
            continue
        stages.append(_Stage("leg", i, i + 1, here, end,
                             _leg_speed(robot, wps[i].speed_mps, here, end), wps[i + 1].stay_s,
                             waiting_s))
        waiting_s = 0.0
        here = end
    last = len(wps) - 1
    if mission.returns_home and math.hypot(here[0] - home[0], here[1] - home[1]) > AT_HOME_M:
        end = (*home, here[2])
        stages.append(_Stage("return", last, 0, here, end,
                             _leg_speed(robot, wps[last].speed_mps, here, end)))
        here = end
    if robot.aerial and here[2] > 0:
        end = (here[0], here[1], 0.0)
        stages.append(_Stage("landing", stages[-1].to_wp if stages else 0,
                             stages[-1].to_wp if stages else 0, here, end,
                             _leg_speed(robot, robot.landing_mps, here, end)))
    if not stages:
        raise InputError(f"{mission.source}: every waypoint is home: nothing to fly")
    return stages


def _with_corners(stages: list[_Stage], mission: Mission, robot: _Robot) -> list[_Stage]:
    """Set the speed allowed through each stage's end (module docstring, step 2)."""
    out = []
    for k, st in enumerate(stages):
        nxt = stages[k + 1] if k + 1 < len(stages) else None
        radius = mission.waypoints[st.to_wp].corner_radius_m if st.kind == "leg" else None
        if nxt is None or st.hold_s > 0 or st.vertical or nxt.vertical or radius is None:
            out.append(st)
            continue
        a, b = st.delta / st.length_m, nxt.delta / nxt.length_m
        turn = math.acos(min(1.0, max(-1.0, float(a @ b))))
        if radius == math.inf or turn < 1e-9:
            speed = math.inf
        else:
            speed = math.sqrt(robot.accel_mps2 * radius / math.tan(turn / 2)) \
                if turn < math.pi - 1e-9 else 0.0
            if speed < CREEP_FRACTION * max(st.speed, nxt.speed):
                speed = 0.0  # slower than the Driver's creep: a stop at the waypoint
        out.append(replace(st, corner_mps=speed, corner_r_m=0.0 if radius == math.inf
                           else radius))
    return out


def _runs(stages: list[_Stage]) -> list[list[int]]:
    """Stage indices grouped into runs between stops (a stop: corner speed 0)."""
    runs, current = [], []
    for k, st in enumerate(stages):
        if st.hold_start_s > 0 and current:
            runs.append(current)
            current = []
        current.append(k)
        if st.corner_mps <= 0:
            runs.append(current)
            current = []
    if current:
        runs.append(current)
    return runs


# --- motion and energy ------------------------------------------------------------------------


class _FlatWorld:
    """Terrain queries of a mission not placed on the map (no origin): flat, default ground."""

    def __init__(self, world):
        self.map = type("FlatMap", (), {"elevation": None})()
        self.default_crr = world.default_crr

    def elevation_at(self, x, y):
        return np.zeros(np.broadcast(np.asarray(x), np.asarray(y)).shape)

    def crr_at(self, x, y):
        return np.full(np.broadcast(np.asarray(x), np.asarray(y)).shape, self.default_crr)

    def surface_code_at(self, x, y):
        return np.full(np.broadcast(np.asarray(x), np.asarray(y)).shape, -1)


def _stages_steps(world, stages: list[_Stage], aerial: bool, step_m: float) -> Steps:
    """Sub-steps of the stages in order, ``segment`` = stage index (``pathcost.Steps``): the
    terrain's (``subdivide``) for ground robots, the stage's own climb spread evenly for
    aerial ones, one sub-step for a vertical stage."""
    start = np.array([st.start for st in stages], float)
    end = np.array([st.end for st in stages], float)
    vertical = np.array([st.vertical for st in stages])
    flat = np.flatnonzero(~vertical)
    parts = []
    if flat.size:
        steps = subdivide(world, start[flat, :2], end[flat, :2], step_m)
        seg = flat[steps.segment]
        if aerial:
            horiz = np.hypot(*(end[flat, :2] - start[flat, :2]).T)[steps.segment]
            dz = (end[seg, 2] - start[seg, 2]) * steps.horiz_m / horiz
            steps = replace(steps, dz_m=dz, length_m=np.hypot(steps.horiz_m, dz))
        parts.append(replace(steps, segment=seg))
    up = np.flatnonzero(vertical)
    if up.size:
        x, y, rise = start[up, 0], start[up, 1], end[up, 2] - start[up, 2]
        zero = np.zeros(up.size)
        parts.append(Steps(segment=up, length_m=np.abs(rise), horiz_m=zero, dz_m=rise,
                           dir_x=zero, dir_y=zero, crr=np.asarray(world.crr_at(x, y), float),
                           surface_code=np.asarray(world.surface_code_at(x, y)),
                           n_segments=up.size))
    merged = Steps.concat(parts)
    order = np.argsort(np.concatenate([p.segment for p in parts]), kind="stable")
    fields = ("length_m", "horiz_m", "dz_m", "dir_x", "dir_y", "crr", "surface_code")
    return Steps(segment=np.concatenate([p.segment for p in parts])[order],
                 n_segments=len(stages), **{f: getattr(merged, f)[order] for f in fields})


def _step_speeds(stages: list[_Stage], steps: Steps, robot: _Robot, dt: float) -> np.ndarray:
    """Cruise speed per sub-step, capped around each corner (braking at ``accel_max`` to the
    corner speed by the start of its arc, one sample of anticipation, held through the arc)."""
    speed = np.array([st.speed for st in stages], float)[steps.segment]
    edges = np.r_[0.0, np.cumsum(steps.length_m)]
    stage_end = edges[np.searchsorted(steps.segment, np.arange(len(stages)), side="right")]
    a = robot.accel_mps2
    top = max(st.speed for st in stages)  # braking may have to start on an earlier stage
    for k, st in enumerate(stages[:-1]):
        v_c = st.corner_mps
        if not (0 < v_c < max(st.speed, stages[k + 1].speed)):
            continue
        s_c, r = stage_end[k], st.corner_r_m
        reach = r + (top**2 - v_c**2) / (2 * a) + a * dt * dt
        lo = np.searchsorted(edges, s_c - reach - 1e-9, side="left")
        hi = np.searchsorted(edges, s_c + r + 1e-9, side="right")
        idx = np.arange(max(lo - 1, 0), min(hi, speed.size))
        before = np.maximum(0.0, s_c - r - edges[idx + 1])
        cap = np.maximum(v_c, np.sqrt(v_c**2 + 2 * a * before) - a * dt)
        cap = np.where(edges[idx] >= s_c, np.where(edges[idx] < s_c + r, v_c, np.inf), cap)
        speed[idx] = np.minimum(speed[idx], cap)
    return speed


def _round_corners(stages: list[_Stage], steps: Steps) -> Steps:
    """Steps with each corner's polyline replaced by the length of its arc.

    The arc is tangent to both legs at ``t = min(r, half of each leg)`` before and after the
    waypoint; for a heading change theta its radius is ``t / tan(theta / 2)`` and its length
    ``t theta / tan(theta / 2)``, shorter than the polyline's ``2 t`` (by 21 % at 90 degrees).
    The sub-steps within ``t`` of the waypoint shrink by that ratio (their grade kept), so a
    survey of short legs turning on 20 m radii is flown in the time the arcs take.
    """
    edges = np.r_[0.0, np.cumsum(steps.length_m)]
    mid = 0.5 * (edges[:-1] + edges[1:])
    stage_end = edges[np.r_[np.flatnonzero(np.diff(steps.segment)) + 1, steps.segment.size]]
    scale = np.ones(steps.length_m.size)
    for k, st in enumerate(stages[:-1]):
        nxt = stages[k + 1]
        if st.corner_r_m <= 0 or st.corner_mps <= 0:
            continue
        a, b = st.delta / st.length_m, nxt.delta / nxt.length_m
        turn = math.acos(min(1.0, max(-1.0, float(a @ b))))
        if turn < 1e-6:
            continue
        t = min(st.corner_r_m, 0.5 * st.length_m, 0.5 * nxt.length_m)
        ratio = turn / (2.0 * math.tan(turn / 2))
        scale[np.abs(mid - stage_end[k]) < t] = ratio
    if np.all(scale == 1.0):
        return steps
    return replace(steps, length_m=steps.length_m * scale, horiz_m=steps.horiz_m * scale,
                   dz_m=steps.dz_m * scale)


@dataclass(frozen=True)
class _Samples:
    """Motion samples of many stages: their MotionState, the time each stands for [s] and the
    label (stage or return index) each is charged to."""

    state: MotionState
    weight_s: np.ndarray
    label: np.ndarray


def _drive(groups, world, robot: _Robot, conditions, step_m: float,
           dt: float = SAMPLE_DT_S) -> _Samples:
    """Samples of ``groups``, pairs (label, stages): each group's stages flown in order, one
    ``Driver`` run between stops, a hold as one sample at rest. A group's samples are charged
    to its label, or (label None) each to its own stage's index."""
    stages = [st for _, group in groups for st in group]
    labels = np.concatenate([np.arange(len(group)) if label is None
                             else np.full(len(group), label) for label, group in groups])
    first = np.cumsum([0] + [len(group) for _, group in groups])
    runs = [[int(first[g] + k) for k in run]
            for g, (_, group) in enumerate(groups) for run in _runs(list(group))]
    steps = _round_corners(stages, _stages_steps(world, stages, robot.aerial, step_m))
    speeds = _step_speeds(stages, steps, robot, dt)
    bounds = np.searchsorted(steps.segment, np.arange(len(stages) + 1), side="left")
    k_spread = max(1, round(TURN_SPREAD_S / dt))
    heading_all = np.arctan2(steps.dir_y, steps.dir_x)
    kins = []
    for run in runs:
        lo, hi = bounds[run[0]], bounds[run[-1] + 1]
        edges = np.r_[0.0, np.cumsum(steps.length_m[lo:hi])]
        kin = _drive_run(edges, speeds[lo:hi], robot.accel_mps2, dt, conditions.duty_cycle)
        j = kin["step"] + lo
        heading = heading_all[j]
        yaw, _ = spread_yaw_rate(heading, heading[0], np.zeros(0), k_spread, dt)
        kins.append({"step": j, "v": kin["v"], "accel": kin["accel"], "yaw": yaw})
    kin = {key: np.concatenate([k[key] for k in kins]) for key in ("step", "v", "accel", "yaw")}
    moving = drive_state(steps, kin, kin["yaw"], conditions.wind_xy_mps, steps.crr[kin["step"]],
                         conditions)
    n_moving = kin["step"].size
    weight = np.full(n_moving, dt)
    label = labels[steps.segment[kin["step"]]]
    holds = [(st.start, st.hold_start_s, labels[k]) for k, st in enumerate(stages)
             if st.hold_start_s > 0] + [(st.end, st.hold_s, labels[k])
                                        for k, st in enumerate(stages) if st.hold_s > 0]
    if not holds:
        return _Samples(moving, weight, label)
    rest = _at_rest(world, np.array([h[0] for h in holds], float), conditions)
    return _Samples(MotionState.concat([moving, rest], [n_moving, len(holds)]),
                    np.r_[weight, [h[1] for h in holds]], np.r_[label, [h[2] for h in holds]])


def _drive_run(edges, speeds, accel: float, dt: float, duty: float) -> dict:
    """``Driver.run`` of one run to its end, asked for about the samples it needs (twice the
    time at the slowest speed plus the ramps, over the duty cycle) so that a short run does not
    allocate the Driver's full chunk, and again until it ends."""
    driver = Driver(edges, speeds, np.ones(speeds.size), accel, dt, duty, STOP_EVERY_S)
    slow = max(float(np.min(speeds)), 1e-3)
    guess = int(2 * (edges[-1] / slow + 2 * float(np.max(speeds)) / accel) / (dt * duty)) + 16
    parts = [driver.run(guess)]
    while not driver.finished:
        if len(parts) >= 8:  # the guess is an upper bound several times over
            raise OrangeError(f"a mission run of {edges[-1]:g} m did not end in "
                              f"{8 * guess * dt:g} s of driving")
        parts.append(driver.run(guess))
    if len(parts) == 1:
        return parts[0]
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}


def _at_rest(world, xyz: np.ndarray, conditions) -> MotionState:
    """Samples at rest at ``xyz`` (n, 3): a hold (hover for an aerial robot) [m]."""
    x, y, n = xyz[:, 0], xyz[:, 1], len(xyz)
    return MotionState(
        speed_mps=np.zeros(n), dir_x=np.zeros(n), dir_y=np.zeros(n),
        wind_x_mps=np.full(n, conditions.wind_xy_mps[0]),
        wind_y_mps=np.full(n, conditions.wind_xy_mps[1]),
        crr=np.asarray(world.crr_at(x, y), float),
        sensor_rate_Hz=np.full(n, conditions.sensor_rate_Hz),
        surface_code=np.asarray(world.surface_code_at(x, y)), channels=conditions.channels)


def _totals(model, samples: _Samples, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Energy [J], gradient d/d theta [J per unit] and time [s] per label, labels 0..n-1."""
    m = samples.label.size
    power = np.broadcast_to(np.asarray(model.power_W(samples.state), float), (m,))
    jac = np.broadcast_to(np.asarray(model.power_jacobian(samples.state), float),
                          (m, len(model.theta)))
    w = samples.weight_s
    energy = np.bincount(samples.label, power * w, minlength=n)
    grad = np.stack([np.bincount(samples.label, jac[:, i] * w, minlength=n)
                     for i in range(jac.shape[1])], axis=-1) if jac.shape[1] else np.zeros((n, 0))
    return energy, grad, np.bincount(samples.label, w, minlength=n)


# --- the check --------------------------------------------------------------------------------


def _context(scenario):
    """A Context from a Context or a Scenario."""
    if hasattr(scenario, "world") and hasattr(scenario, "model"):
        return scenario
    from orange_plan.context import context_of

    return context_of(scenario)


def _check_placement(mission: Mission, world, aerial: bool) -> None:
    """Refuse a mission off the map, or an aerial one below the terrain."""
    xyz = mission.xyz_m
    check_on_map(world, xyz[:, 0], xyz[:, 1], mission.source, "waypoint")
    if aerial:
        ground = world.elevation_at(xyz[:, 0], xyz[:, 1]) - world.elevation_at(xyz[0, 0],
                                                                                xyz[0, 1])
        low = np.flatnonzero(xyz[1:, 2] < ground[1:] - 1e-6)
        if low.size:
            i = int(low[0]) + 1
            raise InputError(f"{mission.source}: waypoint {i} at {xyz[i, 2]:g} m above home is "
                             f"below the ground there ({ground[i]:g} m above home)")


def _samples_per_m(stages: list[_Stage], duty: float, step_m: float) -> float:
    """Upper bound of samples (or sub-steps) per metre of the stages' flight."""
    slowest = min(st.speed for st in stages)
    return max(1.0 / (slowest * SAMPLE_DT_S * duty), 1.0 / step_m)


def _check_size(mission: Mission, stages: list[_Stage], duty: float, step_m: float) -> None:
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
        flat default ground, no placement check

    Raises
    ------
    InputError
        A mission off the map or below the terrain, nothing to fly.
    """
    ctx = _context(scenario)
    conditions = ctx.conditions if wind is None else ctx.conditions.with_wind(wind)
    robot = _robot(ctx)
    if in_map_frame:
        _check_placement(mission, ctx.world, robot.aerial)
        world = ctx.world
    else:
        world = _FlatWorld(ctx.world)
    step_m = max_step_m(world)
    stages = _with_corners(_stages(mission, robot), mission, robot)
    _check_size(mission, stages, conditions.duty_cycle, step_m)
    n = len(stages)
    samples = _drive([(None, stages)], world, robot, conditions, step_m)
    energy, grad, duration = _totals(ctx.model, samples, n)
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
        _leaving_free_space(stages, ctx.world) if in_map_frame else ())


MAX_WARNED_LEGS = 5
"""Legs named one by one in the warning about free space (the rest are counted)."""


def _leaving_free_space(stages: list[_Stage], world) -> tuple[str, ...]:
    """One warning naming the legs whose straight line leaves the map's free space."""
    flat = [st for st in stages if not st.vertical]
    if not flat:
        return ()
    free = world.segments_free([st.start[:2] for st in flat], [st.end[:2] for st in flat])
    bad = [st for st, ok in zip(flat, free) if not ok]
    if not bad:
        return ()
    named = ", ".join(f"{st.kind} {st.from_wp} -> {st.to_wp}" for st in bad[:MAX_WARNED_LEGS])
    more = f" and {len(bad) - MAX_WARNED_LEGS} more" if len(bad) > MAX_WARNED_LEGS else ""
    return (f"{len(bad)} leg(s) leave the map's free space (an obstacle, a no-go zone or the "
            f"boundary, within the robot's keep-away): {named}{more}",)


def mission_samples(mission: Mission, scenario, *, in_map_frame: bool = True):
    """Motion samples of the mission as ``check_mission`` flies it (take-off to landing, no
    way home), and the time each stands for: ``(MotionState, weight_s)``.

    The motion does not depend on the model's coefficients, so one set of samples prices the
    mission under many models: ``sum(model.power_W(state) * weight_s)`` is ``check_mission``'s
    ``energy_J`` under that model (a cross-validation refits the model per fold).
    """
    ctx = _context(scenario)
    robot = _robot(ctx)
    world = ctx.world if in_map_frame else _FlatWorld(ctx.world)
    step_m = max_step_m(world)
    stages = _with_corners(_stages(mission, robot), mission, robot)
    _check_size(mission, stages, ctx.conditions.duty_cycle, step_m)
    samples = _drive([(None, stages)], world, robot, ctx.conditions, step_m)
    return samples.state, samples.weight_s


def _ways_home(stages, mission, world, robot, conditions, step_m, model):
    """Energy [J] and gradient of the way home from each stage's end: a straight leg home
    at that altitude (at the speed leaving the last waypoint, the mission's own return, or
    cruise), then the landing; 0 once home and landed, or at the
    end of a mission that ends away from home."""
    home = (mission.waypoints[0].x_m, mission.waypoints[0].y_m)
    return_speed = mission.waypoints[-1].speed_mps  # the mission's own return (None: cruise)
    groups = []
    for k, st in enumerate(stages):
        if k == len(stages) - 1:
            continue  # the end of the mission: nothing left to fly
        here = st.end
        way = []
        if math.hypot(here[0] - home[0], here[1] - home[1]) > AT_HOME_M:
            end = (*home, here[2])
            way.append(_Stage("return", st.to_wp, 0, here, end,
                              _leg_speed(robot, return_speed, here, end)))
            here = end
        if robot.aerial and here[2] > 0:
            end = (here[0], here[1], 0.0)
            way.append(_Stage("landing", 0, 0, here, end,
                              _leg_speed(robot, robot.landing_mps, here, end)))
        if way:
            groups.append((k, way))
    energy, grad = np.zeros(len(stages)), np.zeros((len(stages), len(model.theta)))
    for batch in _batches(groups, _samples_per_m(stages, conditions.duty_cycle, step_m)):
        samples = _drive(batch, world, robot, conditions, step_m)
        e, g, _ = _totals(model, samples, len(stages))
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


def _worst_wind(model, samples: _Samples, conditions, n: int) -> tuple[float, float]:
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
