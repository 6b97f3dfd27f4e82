"""The stages of a mission as flown, and the speed allowed through each corner.

1. Stages: [take-off: a vertical climb at home], one leg per pair of waypoints (a 3-D straight
   line; aerial robots fly the waypoints' altitudes, ground and marine robots the map's
   terrain, which gives their grade), [the way home], [landing: a vertical descent]. A leg
   without a speed takes the robot's default for its kind: cruise (``Context.cruise_speed_mps``)
   for a leg that moves sideways, ``robot.climb_mps`` / ``robot.descent_mps`` for a vertical
   one, ``robot.landing_mps`` (default: the descent speed) for the final landing (an
   autopilot's automatic landing descends slower than its mission legs: about 1 m/s against
   up to 4 m/s on a DJI Matrice 100); every leg's speed is capped so that its vertical rate
   stays within those speeds and its speed within ``robot.v_max_mps``.
2. Corners: the robot stops at a hold, before and after a vertical stage, at the end, and at
   a waypoint without corner radius ("normal" missions). At a waypoint with corner radius r
   it turns on the arc tangent to both legs that starts r before it; that arc has radius
   ``R = r / tan(theta / 2)`` for a heading change theta, and the robot slows to
   ``v = sqrt(accel_max R)`` (lateral acceleration at most ``accel_max``) by then.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from orange_plan.errors import InputError
from orange_plan.export.missions_in import Mission
from orange_plan.physics.profile import CREEP_FRACTION

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

@dataclass(frozen=True)
class Stage:
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
class RobotLimits:
    """What the stages need from the scenario."""

    aerial: bool
    cruise_mps: float
    climb_mps: float
    descent_mps: float
    v_max_mps: float
    accel_mps2: float
    landing_mps: float


def robot_limits(ctx) -> RobotLimits:
    r = ctx.scenario.robot
    climb = getattr(r, "climb_mps", None) or min(DEFAULT_CLIMB_MPS, r.v_max_mps)
    descent = getattr(r, "descent_mps", None) or min(DEFAULT_DESCENT_MPS, r.v_max_mps)
    landing = getattr(r, "landing_mps", None) or descent
    return RobotLimits(r.kind == "aerial", min(ctx.cruise_speed_mps, r.v_max_mps), climb, descent,
                  r.v_max_mps, r.accel_max_mps2, landing)


def leg_speed(robot: RobotLimits, wanted, start, end) -> float:
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


def mission_stages(mission: Mission, robot: RobotLimits, ground_m=None) -> list[Stage]:
    """The flight as stages, corners not yet set (step 1 of this module's docstring).

    ``mission``'s altitudes are above home (``Mission.above_home``); ``ground_m(x, y)``: the
    ground's height above home [m] where a mission that does not come home lands (None: at
    home's height)."""
    wps = mission.waypoints
    z = [w.z_m if robot.aerial else 0.0 for w in wps]
    home = (wps[0].x_m, wps[0].y_m)
    takeoff = (mission.takeoff_alt_m if mission.takeoff_alt_m is not None else z[0]) \
        if robot.aerial else 0.0
    stages = []
    here = (*home, takeoff)
    waiting_s = wps[0].stay_s  # a hold at home before anything flies
    if takeoff > 0:
        stages.append(Stage("takeoff", 0, 0, (*home, 0.0), here,
                             leg_speed(robot, None, (*home, 0.0), here), waiting_s))
        waiting_s = 0.0
    for i in range(len(wps) - 1):
        end = (wps[i + 1].x_m, wps[i + 1].y_m, z[i + 1])
        if np.linalg.norm(np.subtract(end, here)) == 0:  # a repeated waypoint: only its hold
            if stages:
                stages[-1] = replace(stages[-1], hold_s=stages[-1].hold_s + wps[i + 1].stay_s)
            else:
                waiting_s += wps[i + 1].stay_s
            continue
        stages.append(Stage("leg", i, i + 1, here, end,
                             leg_speed(robot, wps[i].speed_mps, here, end), wps[i + 1].stay_s,
                             waiting_s))
        waiting_s = 0.0
        here = end
    last = len(wps) - 1
    if mission.returns_home:
        stages += way_home(here, home, last, wps[last].speed_mps, robot)
    elif robot.aerial:
        ground = 0.0 if ground_m is None else float(ground_m(here[0], here[1]))
        stages += _landing(here, ground, stages[-1].to_wp if stages else 0, robot)
    if not stages:
        raise InputError(f"{mission.source}: every waypoint is home: nothing to fly")
    return stages


def way_home(here: tuple, home: tuple, at_wp: int, speed_mps, robot: RobotLimits
             ) -> list[Stage]:
    """The way home from ``here`` (x, y, z above home) [m], leaving waypoint ``at_wp``: a
    vertical climb to home's height when below it (no way home passes under its own take-off
    point), a straight leg home at that height at ``speed_mps`` (None: cruise), then the
    landing at home. Empty at home on the ground."""
    way = []
    if robot.aerial and here[2] < 0:
        up = (here[0], here[1], 0.0)
        way.append(Stage("return", at_wp, at_wp, here, up, leg_speed(robot, None, here, up)))
        here = up
    if math.hypot(here[0] - home[0], here[1] - home[1]) > AT_HOME_M:
        end = (*home, here[2])
        way.append(Stage("return", at_wp, 0, here, end, leg_speed(robot, speed_mps, here, end)))
        here = end
    if robot.aerial:
        way += _landing(here, 0.0, way[-1].to_wp if way else at_wp, robot)
    return way


def _landing(here: tuple, ground: float, at_wp: int, robot: RobotLimits) -> list[Stage]:
    """The vertical descent from ``here`` to the ground's height ``ground`` [m] (none when
    at or below it)."""
    if here[2] <= ground:
        return []
    end = (here[0], here[1], ground)
    return [Stage("landing", at_wp, at_wp, here, end,
                  leg_speed(robot, robot.landing_mps, here, end))]


def with_corners(stages: list[Stage], mission: Mission, robot: RobotLimits) -> list[Stage]:
    """Set the speed allowed through each stage's end (step 2 of this module's docstring)."""
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


def runs_between_stops(stages: list[Stage]) -> list[list[int]]:
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
