"""The speed profile a robot drives along a path, shared by the planner and the simulator.

A plan's energy must cover what the robot draws when it drives the plan, and the SPEC §7
straight-segment figure (cruise speed throughout) does not: the robot starts and ends at
rest, changes speed at ``accel_max_mps2`` and stops on its duty cycle. This module is the one
description of that motion. ``Driver`` steps it in time; ``drive_state`` turns its samples
into the ``MotionState`` the energy model evaluates; ``profile_energy`` integrates the model's
power along it. The simulator (``sim.simulator``) drives the same ``Driver`` and adds only its
truth-only effects, so a planned energy and the simulated draw of the same path under the same
model agree to the sampling of the power.

The motion (Notes of ``Driver``): accelerate at ``a_max`` towards each sub-step's cruise speed;
after every ``stop_every_s`` of moving time brake at ``a_max`` to rest and wait until moving
time / mission time is back to the duty cycle D; brake to rest at the end of the path and wait
out the duty cycle there too, so the mission time is the moving time / D (SPEC §7's
``L / (v D)`` with the moving time of the real profile).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from orange_plan.physics.conditions import Conditions
from orange_plan.physics.ops import wrap_pi
from orange_plan.physics.state import MotionState

STOP_EVERY_S = 60.0
"""Moving time between duty-cycle stops [s]: the planner's assumption and the simulator's
default (a truth file may change the simulator's)."""

SAMPLE_DT_S = 0.1
"""Time step of the profile [s]: the simulator's default recording period (10 Hz)."""

TURN_SPREAD_S = 1.0
"""A vertex's heading change is spread over this time, as a robot turns smoothly [s]."""

CREEP_FRACTION = 0.05
"""Slowest approach to the end of a path, as a fraction of cruise: the end is reached in finite
time although the braking curve alone would approach it asymptotically on a discrete clock."""


class Driver:
    """Point-mass kinematics along a path with acceleration limits and duty-cycle stops.

    Parameters
    ----------
    edges_m : horizontal arclength at the sub-step edges, shape (n + 1,) [m]
    step_speed : cruise speed along the path per sub-step, shape (n,) [m/s]
    step_cos : cosine of each sub-step's grade, shape (n,) [-]
    accel_max : acceleration and braking limit [m/s^2]
    dt : time step [s]
    duty : duty cycle D, moving time / mission time [-]
    stop_every_s : moving time between stops [s]
    repeat : drive the path again and again (a lap; no end) instead of once

    Notes
    -----
    Speeds are along the path; the horizontal arclength advances by ``v cos(grade) dt`` (the
    mean of the step's start and end speeds). Each step's speed change is
    ``clip(target - v, -a dt, a dt)`` with target the sub-step's cruise speed, 0 while
    stopping, and near the end ``sqrt(2 a remaining) - a dt`` (brake to rest on arrival; the
    ``- a dt`` is one step of anticipation, as the speed follows the cap with a step's lag).
    Stops: after ``stop_every_s`` of moving, brake to rest and wait until ``t >= moving / D``;
    at the end of a single run the same wait once at rest, so the run's moving time / mission
    time is D (SPEC §7's mission time, moving time / D).
    """

    def __init__(self, edges_m, step_speed, step_cos, accel_max, dt, duty,
                 stop_every_s=STOP_EVERY_S, repeat=False):
        self.edges = [float(e) for e in edges_m]
        self.length = self.edges[-1]
        self.speed = [float(v) for v in step_speed]
        self.cos = [float(c) for c in step_cos]
        self.a, self.dt, self.duty = float(accel_max), float(dt), float(duty)
        self.every, self.repeat = float(stop_every_s), repeat
        self.s = self.v = self.t = self.moving = 0.0
        self.phase, self.next_stop = "move", self.every
        self.arrived = self.finished = False

    def run(self, n: int) -> dict:
        """The next ``n`` samples (fewer when the path ends): arrays ``t`` [s], ``s`` [m]
        (horizontal arclength driven, laps included), ``v`` [m/s], ``accel`` [m/s^2] over the
        sample, ``step`` (sub-step index).

        One Python iteration per sample is the planner's inner loop (every walk, return and
        replan is driven), so the state lives in locals and the sub-step is a pointer that
        only moves forwards (the arclength never decreases; laps look it up again): the
        arithmetic is the Notes' rule, in the same order as before this loop was inlined.
        """
        t_out, s_out, v_out, a_out, j_out = [], [], [], [], []
        edges, speed, cos = self.edges, self.speed, self.cos
        n_steps, length, repeat = len(speed), self.length, self.repeat
        a, dt, duty, every = self.a, self.dt, self.duty, self.every
        a_dt, two_a = a * dt, 2 * a
        stops = duty < 1.0
        s, v, t, moving = self.s, self.v, self.t, self.moving
        phase, next_stop, arrived = self.phase, self.next_stop, self.arrived
        finished = self.finished
        j = min(bisect_right(edges, s % length if repeat else min(s, length)) - 1, n_steps - 1)
        last_lap = s % length if repeat else 0.0
        for _ in range(n):
            if finished:
                break
            if repeat:
                lap_s = s % length
                if lap_s < last_lap:  # a new lap: look the sub-step up again
                    j = min(bisect_right(edges, lap_s) - 1, n_steps - 1)
                last_lap = lap_s
            else:
                lap_s = s if s < length else length
            while j < n_steps - 1 and edges[j + 1] <= lap_s:
                j += 1
            # the target speed (``_target``)
            if arrived:
                target = 0.0
            else:
                target = cruise = speed[j]
                if stops:
                    if phase == "move" and moving >= next_stop:
                        phase = "brake"
                    if phase == "brake" and v <= 0:
                        phase = "stop"
                    if phase == "stop" and t >= moving / duty:
                        phase, next_stop = "move", moving + every
                    if phase != "move":
                        target = 0.0
                if target and not repeat:
                    remaining = length - s if length > s else 0.0
                    brake = math.sqrt(two_a * remaining) - a_dt
                    creep = CREEP_FRACTION * cruise
                    target = min(cruise, brake if brake > creep else creep)
            dv = target - v
            v_new = v + (a_dt if dv > a_dt else (-a_dt if dv < -a_dt else dv))
            if v_new < 0.0:
                v_new = 0.0
            t_out.append(t)
            s_out.append(s)
            v_out.append(v)
            a_out.append((v_new - v) / dt)
            j_out.append(j)
            if v > 0 or v_new > 0:
                moving += dt
            s += 0.5 * (v + v_new) * dt * cos[j]
            v, t = v_new, t + dt
            if not repeat and length - s <= 1e-6:
                arrived = True
            if arrived and v <= 0 and t >= moving / duty - 1e-9:
                finished = True  # at rest at the end, the duty cycle waited out
        self.s, self.v, self.t, self.moving = s, v, t, moving
        self.phase, self.next_stop, self.arrived, self.finished = phase, next_stop, arrived, finished
        return {"t": np.asarray(t_out), "s": np.asarray(s_out), "v": np.asarray(v_out),
                "accel": np.asarray(a_out), "step": np.asarray(j_out, dtype=int)}

def spread_yaw_rate(heading, last_heading, carry, k: int, dt: float):
    """Heading increments spread over ``k`` samples (causal box filter) -> yaw rate [rad/s].

    Returns the yaw rate of the samples and the carry (increments still to be spread) for
    the next call.
    """
    inc = wrap_pi(np.diff(np.r_[last_heading, heading]))
    spread = np.convolve(inc, np.ones(k) / k)
    spread[: carry.size] += carry
    n = heading.size
    return spread[:n] / dt, spread[n:]


def drive_state(steps, kin: dict, yaw_rate_radps, wind_xy_mps, crr,
                conditions: Conditions) -> MotionState:
    """MotionState of driven samples on the sub-steps ``steps`` (``pathcost.Steps``).

    ``wind_xy_mps`` (2,) or (n, 2) and ``crr`` (n,) are passed in because the simulator
    perturbs them (gusts, roughness); the planner passes the mean wind and ``steps.crr``.
    The sensor rate and the temperature channels come from ``conditions``.
    """
    j = kin["step"]
    wind = np.broadcast_to(np.asarray(wind_xy_mps, float), (j.size, 2))
    return MotionState(
        speed_mps=kin["v"], cos_t=steps.cos_t[j], sin_t=steps.sin_t[j], dir_x=steps.dir_x[j],
        dir_y=steps.dir_y[j], wind_x_mps=wind[:, 0], wind_y_mps=wind[:, 1], crr=crr,
        accel_mps2=kin["accel"], yaw_rate_radps=yaw_rate_radps,
        sensor_rate_Hz=np.full(j.size, conditions.sensor_rate_Hz),
        surface_code=steps.surface_code[j], channels=conditions.channels)


def step_headings_rad(steps) -> np.ndarray:
    """Heading of each sub-step [rad]."""
    return np.arctan2(steps.dir_y, steps.dir_x)


@dataclass(frozen=True)
class ProfileEnergy:
    """Energy drawn along a driven profile (rectangle rule over the samples, as recorded).

    Attributes
    ----------
    t_s : sample times, shape (n,) [s]; s_m : horizontal arclength at each sample [m]
    cumulative_J : energy drawn by the end of each sample, shape (n,) [J]
    dt_s : sample period [s]
    """

    t_s: np.ndarray
    s_m: np.ndarray
    cumulative_J: np.ndarray
    dt_s: float

    @property
    def total_J(self) -> float:
        return float(self.cumulative_J[-1])

    @property
    def duration_s(self) -> float:
        """Mission time, the final wait included [s]."""
        return float(self.t_s[-1] + self.dt_s)

    def at_arclength(self, s_m) -> tuple[np.ndarray, np.ndarray]:
        """(energy drawn [J], time [s]) when the robot first reaches each arclength ``s_m``."""
        return self.drawn_before(self.cumulative_J, s_m), self.t_s[self._first_sample(s_m)]

    def drawn_before(self, cumulative, s_m) -> np.ndarray:
        """A per-sample cumulative sum (energy, its gradient: leading axis = samples) as it
        stands when the robot first reaches each arclength ``s_m``."""
        i = self._first_sample(s_m)
        cumulative = np.asarray(cumulative)
        first = (i == 0).reshape(i.shape + (1,) * (cumulative.ndim - 1))
        return np.where(first, 0.0, cumulative[np.maximum(i - 1, 0)])

    def _first_sample(self, s_m) -> np.ndarray:
        i = np.searchsorted(self.s_m, np.asarray(s_m, float) - 1e-9, side="left")
        return np.clip(i, 0, self.t_s.size - 1)


def drive_path(steps, step_speed_mps, accel_max_mps2: float, conditions: Conditions,
               dt_s: float = SAMPLE_DT_S,
               stop_every_s: float = STOP_EVERY_S) -> tuple[dict, MotionState]:
    """Drive sub-steps once with ``Driver``: the samples (``Driver.run``'s arrays) and their
    MotionState (mean wind, the map's crr, heading changes spread over ``TURN_SPREAD_S``).

    Parameters
    ----------
    steps : ``pathcost.Steps`` of the path, in order (at least one of positive length)
    step_speed_mps : cruise speed per sub-step [m/s]
    accel_max_mps2 : acceleration limit [m/s^2]
    conditions : duty cycle, sensor rate and mean wind (``physics.conditions``)
    dt_s : time step [s]; stop_every_s : moving time between duty-cycle stops [s]
    """
    edges = np.r_[0.0, np.cumsum(steps.horiz_m)]
    driver = Driver(edges, step_speed_mps, steps.cos_t, accel_max_mps2, dt_s,
                    conditions.duty_cycle, stop_every_s)
    chunks = []
    while not driver.finished:
        chunks.append(driver.run(100_000))
    kin = {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}
    heading = step_headings_rad(steps)[kin["step"]]
    yaw, _ = spread_yaw_rate(heading, heading[0], np.zeros(0), max(1, round(TURN_SPREAD_S / dt_s)),
                             dt_s)
    return kin, drive_state(steps, kin, yaw, conditions.wind_xy_mps, steps.crr[kin["step"]],
                            conditions)


def profile_energy(model, steps, step_speed_mps, accel_max_mps2: float, conditions: Conditions,
                   dt_s: float = SAMPLE_DT_S, stop_every_s: float = STOP_EVERY_S) -> ProfileEnergy:
    """Energy of the profile ``drive_path`` drives (parameters as there).

    Notes
    -----
    ``E = sum_k P(state_k) dt`` with ``P`` = ``EnergyModel.power_W`` (time domain: inertia,
    regen and the rate terms all apply): the energy the simulator draws on the same path with
    no truth-only effects.
    """
    kin, state = drive_path(steps, step_speed_mps, accel_max_mps2, conditions, dt_s,
                            stop_every_s)
    return _drawn(model, kin, state, dt_s)


def profile_energy_and_gradient(model, steps, step_speed_mps, accel_max_mps2: float,
                                conditions: Conditions, dt_s: float = SAMPLE_DT_S,
                                stop_every_s: float = STOP_EVERY_S):
    """``profile_energy`` and the running sum of d(power)/d theta dt over the same samples,
    shape (n, k), from one drive (a plan's per-vertex energies and reserve gradients)."""
    kin, state = drive_path(steps, step_speed_mps, accel_max_mps2, conditions, dt_s,
                            stop_every_s)
    return _drawn(model, kin, state, dt_s), np.cumsum(model.power_jacobian(state), axis=0) * dt_s


def _drawn(model, kin: dict, state: MotionState, dt_s: float) -> ProfileEnergy:
    """Energy drawn along driven samples: the model's power, rectangle rule."""
    power = np.broadcast_to(np.asarray(model.power_W(state), float), kin["t"].shape)
    return ProfileEnergy(kin["t"], kin["s"], np.cumsum(power) * dt_s, dt_s)


def profile_gradient(model, steps, step_speed_mps, accel_max_mps2: float,
                     conditions: Conditions, dt_s: float = SAMPLE_DT_S,
                     stop_every_s: float = STOP_EVERY_S) -> np.ndarray:
    """d(profile energy)/d theta, shape (k,): ``sum_k dP/dtheta(state_k) dt`` (reserve sizing;
    ``gradient @ theta`` is the profile energy for models without regen)."""
    _, state = drive_path(steps, step_speed_mps, accel_max_mps2, conditions, dt_s, stop_every_s)
    return model.power_jacobian(state).sum(axis=0) * dt_s


# --- many independent single runs at once ---------------------------------------------------


def _drive_kinematics(edges_list, speed_list, cos_list, accel_max: float, dt: float,
                      duty: float, stop_every_s: float) -> list[dict]:
    """``Driver.run``'s arrays for many independent single runs (``repeat=False``), stepped
    together: one numpy loop over time steps with arrays of one entry per path.

    Notes
    -----
    Each path follows the scalar ``Driver``'s arithmetic, the same operations in the same
    order, so its samples are the same floating-point numbers. What differs is form only:

    * sub-step lookup: a pointer per path into one array of all paths' sub-step end edges
      (each path's last edge replaced by ``inf``), advanced while the next edge is ``<= s``.
      The arclength never decreases, so the pointer only moves forwards and lands where
      ``min(bisect_right(edges, min(s, length)) - 1, n - 1)`` does; when every sub-step (but
      a path's last) is longer than a time step can drive, one advance per step is enough.
    * duty-cycle phases as flags, checked only when they can change (a moving time cannot
      pass a stop before the clock does: both add up the same ``dt``). After arrival the
      ``Driver`` never reads its phase again (the target is 0), so it is not kept up there.
    * a finished path (at rest at its end, target 0) no longer changes; it is no longer
      recorded. ``accel`` is ``(v[k + 1] - v[k]) / dt`` of the recorded speeds, the division
      ``Driver`` does.
    """
    n = len(edges_list)
    n_sub = np.array([len(v) for v in speed_list], dtype=np.intp)
    s_off = np.r_[0, np.cumsum(n_sub)[:-1]].astype(np.intp)
    edges = [np.asarray(e, float) for e in edges_list]
    upper = np.concatenate([np.r_[e[1:-1], np.inf] for e in edges])
    length = np.array([e[-1] for e in edges])
    speed = np.concatenate([np.asarray(v, float) for v in speed_list])
    cos = np.concatenate([np.asarray(c, float) for c in cos_list])
    creep = CREEP_FRACTION * speed

    a, dt, duty, every = float(accel_max), float(dt), float(duty), float(stop_every_s)
    a_dt, two_a = a * dt, 2 * a
    inner = np.concatenate([np.diff(e[:-1]) for e in edges])  # sub-steps but the last
    v_top = float(speed.max(initial=0.0))
    single = inner.size == 0 or float(inner.min()) > v_top * dt * (1 + 1e-6) + 1e-9

    zero, lo, hi = np.zeros(n), np.full(n, -a_dt), np.full(n, a_dt)
    s, v, moving = np.zeros(n), np.zeros(n), np.zeros(n)
    rem = length - s
    stops = duty < 1.0
    braking, stopped = np.zeros(n, bool), np.zeros(n, bool)
    any_braking = any_stopped = False
    next_stop = np.full(n, every)
    first_stop = every
    arrived, finished, waiting = np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool)
    halt = arrived
    n_arrived = 0
    g = s_off.copy()  # global sub-step index of each path
    n_samples = np.zeros(n, dtype=np.intp)
    chunk = 4096
    rec_s, rec_v = np.empty((chunk, n)), np.empty((chunk + 1, n))
    rec_g = np.empty((chunk, n), dtype=np.intp)
    t, k = 0.0, 0
    t_out = []
    while True:
        if k == rec_s.shape[0]:
            rec_s = np.concatenate([rec_s, np.empty((chunk, n))])
            rec_v = np.concatenate([rec_v, np.empty((chunk, n))])
            rec_g = np.concatenate([rec_g, np.empty((chunk, n), dtype=np.intp)])
        # sub-step: Driver's bisect on min(s, length), clipped to the last sub-step
        g += upper[g] <= s
        if not single:
            while True:
                ahead = upper[g] <= s
                if not np.count_nonzero(ahead):
                    break
                g += ahead
        cruise = speed[g]
        # Driver.run's target speed
        if stops:
            changed = False
            if t >= first_stop:  # moving <= t: no stop is due before
                hit = moving >= next_stop  # next_stop is inf unless moving
                if np.count_nonzero(hit):
                    braking |= hit
                    next_stop[hit] = np.inf
                    any_braking = changed = True
                first_stop = float(next_stop.min())
            if any_braking:
                rest = braking & (v <= zero)
                if np.count_nonzero(rest):
                    braking &= ~rest
                    stopped |= rest
                    any_braking = bool(np.count_nonzero(braking))
                    any_stopped = changed = True
            if any_stopped:
                go = stopped & (t >= moving / duty)
                if np.count_nonzero(go):
                    stopped &= ~go
                    next_stop = np.where(go, moving + every, next_stop)
                    first_stop = float(next_stop.min())
                    any_stopped = bool(np.count_nonzero(stopped))
                    changed = True
            if changed:
                halt = arrived | braking | stopped
        np.maximum(rem, zero, out=rem)
        brake = np.sqrt(two_a * rem)
        brake -= a_dt
        np.maximum(brake, creep[g], out=brake)
        target = np.minimum(cruise, brake, out=brake)
        target[halt] = 0.0
        # the step
        dv = target - v
        np.maximum(dv, lo, out=dv)
        np.minimum(dv, hi, out=dv)
        v_new = v + dv
        np.maximum(zero, v_new, out=v_new)
        t_out.append(t)
        rec_s[k] = s
        rec_v[k] = v
        rec_g[k] = g
        both = v + v_new
        moving = np.where(both > zero, moving + dt, moving)  # v, v_new >= 0
        both *= 0.5
        both *= dt
        both *= cos[g]
        s = s + both
        v, t = v_new, t + dt
        k += 1
        rem = length - s
        arrived |= rem <= 1e-6
        n_now = int(np.count_nonzero(arrived))
        if n_now != n_arrived:
            n_arrived = n_now
            waiting = arrived & ~finished
            halt = arrived | braking | stopped if stops else arrived
        if n_arrived:
            done = waiting & (v <= zero)
            if np.count_nonzero(done):
                done &= t >= moving / duty - 1e-9
                if np.count_nonzero(done):
                    n_samples[done] = k
                    finished |= done
                    waiting &= ~done
                    if not np.count_nonzero(waiting) and n_arrived == n:
                        break
    rec_v[k] = v
    accel = ((rec_v[1:k + 1] - rec_v[:k]) / dt).T.copy()
    # path-major (n, k): each path's samples contiguous, its first n_samples[p] valid
    return (np.asarray(t_out), rec_s[:k].T.copy(), rec_v[:k].T.copy(), accel,
            (rec_g[:k] - s_off).T.astype(int), n_samples)


def _split_kinematics(records) -> list[dict]:
    """``_drive_kinematics``' records as one ``Driver.run`` dict per path."""
    t_all, s_rec, v_rec, accel, j_rec, n_samples = records
    return [{"t": t_all[:m].copy(), "s": s_rec[p, :m].copy(), "v": v_rec[p, :m].copy(),
             "accel": accel[p, :m].copy(), "step": j_rec[p, :m].copy()}
            for p, m in enumerate(n_samples.tolist())]


def _path_kinematics(steps_list, step_speed_list, accel_max_mps2, duty_cycle, dt_s,
                     stop_every_s) -> tuple:
    if len(steps_list) != len(step_speed_list):
        raise ValueError(f"{len(steps_list)} paths but {len(step_speed_list)} speed arrays")
    edges = [np.r_[0.0, np.cumsum(st.horiz_m)] for st in steps_list]
    return _drive_kinematics(edges, step_speed_list, [st.cos_t for st in steps_list],
                             accel_max_mps2, dt_s, duty_cycle, stop_every_s)


def _yaw_rate(steps, kin: dict, dt_s: float) -> np.ndarray:
    heading = step_headings_rad(steps)[kin["step"]]
    yaw, _ = spread_yaw_rate(heading, heading[0], np.zeros(0),
                             max(1, round(TURN_SPREAD_S / dt_s)), dt_s)
    return yaw


def drive_paths(steps_list, step_speed_list, accel_max_mps2: float, conditions: Conditions,
                dt_s: float = SAMPLE_DT_S,
                stop_every_s: float = STOP_EVERY_S) -> list[tuple[dict, MotionState]]:
    """``drive_path`` of many independent paths at once: for each, the same samples and
    MotionState as ``drive_path`` gives it (parameters as there, ``steps_list`` and
    ``step_speed_list`` one entry per path).

    The kinematics of all paths advance together in one numpy loop over time steps (the
    scalar ``Driver`` costs a Python iteration per sample and path), with the ``Driver``'s
    arithmetic in the same order, so the samples are those of ``drive_path``.
    """
    if not len(steps_list) and not len(step_speed_list):
        return []
    kins = _split_kinematics(_path_kinematics(steps_list, step_speed_list, accel_max_mps2,
                                              conditions.duty_cycle, dt_s, stop_every_s))
    return [(kin, drive_state(steps, kin, _yaw_rate(steps, kin, dt_s), conditions.wind_xy_mps,
                              steps.crr[kin["step"]], conditions))
            for steps, kin in zip(steps_list, kins)]


def profile_energies_and_gradients(model, steps_list, step_speed_list, accel_max_mps2: float,
                                   conditions: Conditions, dt_s: float = SAMPLE_DT_S,
                                   stop_every_s: float = STOP_EVERY_S
                                   ) -> tuple[np.ndarray, np.ndarray]:
    """Profile energy [J], shape (n,), and its gradient d/d theta, shape (n, k), of many paths:
    per path ``profile_energy(...).total_J`` and ``profile_gradient(...)`` (parameters as
    ``drive_paths``), from one drive of all paths and one evaluation of the model's power and
    Jacobian over all their samples (the model's terms are per sample)."""
    k = len(model.theta)
    n = len(steps_list)
    if n == 0 and not len(step_speed_list):
        return np.zeros(0), np.zeros((0, k))
    t_all, _, v_rec, accel, j_rec, n_samples = _path_kinematics(
        steps_list, step_speed_list, accel_max_mps2, conditions.duty_cycle, dt_s, stop_every_s)
    valid = np.arange(t_all.size) < n_samples[:, None]  # path-major, as the records
    bounds = np.r_[0, np.cumsum(n_samples)]
    step_off = np.r_[0, np.cumsum([st.horiz_m.size for st in steps_list])[:-1]]
    j = j_rec[valid] + np.repeat(step_off, n_samples)  # into the concatenated sub-steps
    steps = steps_list[0].concat(steps_list)  # pathcost imports this module: no import back
    heading = step_headings_rad(steps)[j]
    k_spread = max(1, round(TURN_SPREAD_S / dt_s))
    yaw = np.concatenate([spread_yaw_rate(heading[lo:hi], heading[lo], np.zeros(0), k_spread,
                                          dt_s)[0] for lo, hi in pairwise(bounds)])
    kin = {"step": j, "v": v_rec[valid], "accel": accel[valid]}
    state = drive_state(steps, kin, yaw, conditions.wind_xy_mps, steps.crr[j], conditions)
    power = np.broadcast_to(np.asarray(model.power_W(state), float), j.shape)
    jac = np.broadcast_to(np.asarray(model.power_jacobian(state), float), (j.size, k))
    energy, gradient = np.empty(n), np.empty((n, k))
    for p in range(n):  # the reductions of profile_energy / profile_gradient, path by path
        lo, hi = bounds[p], bounds[p + 1]
        energy[p] = np.cumsum(power[lo:hi])[-1] * dt_s
        gradient[p] = jac[lo:hi].sum(axis=0) * dt_s
    return energy, gradient
