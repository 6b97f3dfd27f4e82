"""Motion samples and energy of mission stages (``planning.mission_stages``).

Between stops the robot drives the profile of ``physics.profile.Driver`` (the planner's and
the simulator's): acceleration and braking at ``accel_max_mps2``, duty-cycle stops, at rest at
both ends; it brakes at ``accel_max`` to each corner's speed by the start of its arc. The
arc's length replaces the polyline's ``2 r`` around the waypoint (``_round_corners``: 21 %
shorter at 90 degrees; a survey of 40 m legs on 20 m radii is mostly arcs). The energy is the
scenario's energy model (``EnergyModel.power_W``) on the motion samples (speed, acceleration,
grade, heading, wind, yaw rate), a hold being samples at rest, so any term the model has (a
calibrated one included) counts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from orange_plan.errors import OrangeError
from orange_plan.physics.pathcost import Steps, subdivide
from orange_plan.physics.profile import (
    SAMPLE_DT_S,
    STOP_EVERY_S,
    TURN_SPREAD_S,
    Driver,
    drive_state,
    spread_yaw_rate,
)
from orange_plan.physics.state import MotionState
from orange_plan.planning.mission_stages import RobotLimits, Stage, runs_between_stops


class FlatWorld:
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


def _stages_steps(world, stages: list[Stage], aerial: bool, step_m: float) -> Steps:
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


def _step_speeds(stages: list[Stage], steps: Steps, robot: RobotLimits, dt: float) -> np.ndarray:
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


def _round_corners(stages: list[Stage], steps: Steps) -> Steps:
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
class Samples:
    """Motion samples of many stages: their MotionState, the time each stands for [s] and the
    label (stage or return index) each is charged to."""

    state: MotionState
    weight_s: np.ndarray
    label: np.ndarray


def drive(groups, world, robot: RobotLimits, conditions, step_m: float,
           dt: float = SAMPLE_DT_S) -> Samples:
    """Samples of ``groups``, pairs (label, stages): each group's stages flown in order, one
    ``Driver`` run between stops, a hold as one sample at rest. A group's samples are charged
    to its label, or (label None) each to its own stage's index."""
    stages = [st for _, group in groups for st in group]
    labels = np.concatenate([np.arange(len(group)) if label is None
                             else np.full(len(group), label) for label, group in groups])
    first = np.cumsum([0] + [len(group) for _, group in groups])
    runs = [[int(first[g] + k) for k in run]
            for g, (_, group) in enumerate(groups) for run in runs_between_stops(list(group))]
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
        return Samples(moving, weight, label)
    rest = _at_rest(world, np.array([h[0] for h in holds], float), conditions)
    return Samples(MotionState.concat([moving, rest], [n_moving, len(holds)]),
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


def energy_totals(model, samples: Samples, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
