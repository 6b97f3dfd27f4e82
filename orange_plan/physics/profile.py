"""The speed profile a robot drives along a path, shared by the planner and the simulator.

A plan's energy must cover what the robot draws when it drives the plan, and the reference-model
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
out the duty cycle there too, so the mission time is the moving time / D (the reference model's
``L / (v D)`` with the moving time of the real profile).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

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
    time is D (the reference model's mission time, moving time / D).
    """

    def __init__(self, edges_m, step_speed, step_cos, accel_max, dt, duty,
                 stop_every_s=STOP_EVERY_S, repeat=False):
        self.edges = np.ascontiguousarray(edges_m, dtype=float)
        self.length = float(self.edges[-1])
        self.speed = np.ascontiguousarray(step_speed, dtype=float)
        self.cos = np.ascontiguousarray(step_cos, dtype=float)
        self.a, self.dt, self.duty = float(accel_max), float(dt), float(duty)
        self.every, self.repeat = float(stop_every_s), bool(repeat)
        self.s = self.v = self.t = self.moving = 0.0
        self.phase, self.next_stop = _MOVE, self.every
        self.arrived = self.finished = False

    def run(self, n: int) -> dict:
        """The next ``n`` samples (fewer when the path ends): arrays ``t`` [s], ``s`` [m]
        (horizontal arclength driven, laps included), ``v`` [m/s], ``accel`` [m/s^2] over the
        sample, ``step`` (sub-step index).

        Every walk, return and replan is driven, one iteration per sample: the loop is
        ``_drive_steps``, compiled (``_compiled_drive_steps``), in chunks so that a large
        ``n`` does not allocate what a short path never fills.
        """
        kernel = _compiled_drive_steps()
        chunks = []
        left = int(n)
        while left > 0 and not self.finished:
            size = min(left, _RUN_CHUNK)
            out = (np.empty(size), np.empty(size), np.empty(size), np.empty(size),
                   np.empty(size, dtype=np.int64))
            (k, self.s, self.v, self.t, self.moving, self.phase, self.next_stop, self.arrived,
             self.finished) = kernel(
                self.edges, self.speed, self.cos, self.a, self.dt, self.duty, self.every,
                self.repeat, size, self.s, self.v, self.t, self.moving, self.phase,
                self.next_stop, self.arrived, self.finished, *out)
            chunks.append([a[:k] for a in out])
            left -= k
            if k < size:
                break
        if not chunks:
            chunks = [[np.empty(0)] * 4 + [np.empty(0, dtype=np.int64)]]
        t, s, v, accel, step = (np.concatenate(c) if len(chunks) > 1 else c[0].copy()
                                for c in zip(*chunks))
        return {"t": t, "s": s, "v": v, "accel": accel, "step": step.astype(int, copy=False)}


_MOVE, _BRAKE, _STOP = 0, 1, 2
"""Duty-cycle phases of ``Driver``: moving, braking for a stop, stopped."""

_RUN_CHUNK = 16_384
"""Samples per compiled call of ``Driver.run`` (arrays allocated per call)."""


def _drive_steps(edges, speed, cos, a, dt, duty, every, repeat, n, s, v, t, moving, phase,
                 next_stop, arrived, finished, t_out, s_out, v_out, a_out, j_out):
    """``Driver.run``'s loop: up to ``n`` samples from the state (s .. finished) into the
    ``*_out`` arrays; returns the samples written and the new state.

    Plain Python that numba compiles (``_compiled_drive_steps``): the rule of ``Driver``'s
    Notes, the operations in the order of the interpreted loop it replaces, so the samples
    are the same floating-point numbers (tests/driver_reference.py is that loop). The
    sub-step is a pointer that only moves forwards (the arclength never decreases; a new lap
    looks it up again).
    """
    n_steps = speed.size
    length = edges[-1]
    a_dt, two_a = a * dt, 2 * a
    stops = duty < 1.0
    if repeat:
        last_lap = s % length
        j = min(np.searchsorted(edges, last_lap, side="right") - 1, n_steps - 1)
    else:
        last_lap = 0.0
        j = min(np.searchsorted(edges, min(s, length), side="right") - 1, n_steps - 1)
    k = 0
    while k < n and not finished:
        if repeat:
            lap_s = s % length
            if lap_s < last_lap:  # a new lap: look the sub-step up again
                j = min(np.searchsorted(edges, lap_s, side="right") - 1, n_steps - 1)
            last_lap = lap_s
        else:
            lap_s = s if s < length else length
        while j < n_steps - 1 and edges[j + 1] <= lap_s:
            j += 1
        if arrived:
            target = 0.0
        else:
            target = cruise = speed[j]
            if stops:
                if phase == _MOVE and moving >= next_stop:
                    phase = _BRAKE
                if phase == _BRAKE and v <= 0:
                    phase = _STOP
                if phase == _STOP and t >= moving / duty:
                    phase, next_stop = _MOVE, moving + every
                if phase != _MOVE:
                    target = 0.0
            if target != 0.0 and not repeat:
                remaining = length - s if length > s else 0.0
                brake = math.sqrt(two_a * remaining) - a_dt
                creep = CREEP_FRACTION * cruise
                target = min(cruise, brake if brake > creep else creep)
        dv = target - v
        v_new = v + (a_dt if dv > a_dt else (-a_dt if dv < -a_dt else dv))
        if v_new < 0.0:
            v_new = 0.0
        t_out[k] = t
        s_out[k] = s
        v_out[k] = v
        a_out[k] = (v_new - v) / dt
        j_out[k] = j
        k += 1
        if v > 0 or v_new > 0:
            moving += dt
        s += 0.5 * (v + v_new) * dt * cos[j]
        v, t = v_new, t + dt
        if not repeat and length - s <= 1e-6:
            arrived = True
        if arrived and v <= 0 and t >= moving / duty - 1e-9:
            finished = True  # at rest at the end, the duty cycle waited out
    return k, s, v, t, moving, phase, next_stop, arrived, finished


@functools.cache
def _compiled_drive_steps():
    """``_drive_steps`` compiled by numba on first use (imported here, not at module import:
    commands that never drive a path do not pay numba's import). ``cache=True`` keeps the
    machine code on disk next to this module, so later processes load it instead of compiling."""
    from numba import njit

    try:
        return njit(cache=True, nogil=True)(_drive_steps)
    except RuntimeError:  # numba found no writable cache location: compile in memory instead
        return njit(nogil=True)(_drive_steps)


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
    kin = _drive_once(steps, step_speed_mps, accel_max_mps2, conditions.duty_cycle, dt_s,
                      stop_every_s)
    return kin, drive_state(steps, kin, _yaw_rate(steps, kin, dt_s), conditions.wind_xy_mps,
                            steps.crr[kin["step"]], conditions)


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


def _drive_once(steps, step_speed_mps, accel_max_mps2: float, duty_cycle: float, dt_s: float,
                stop_every_s: float) -> dict:
    """``Driver.run``'s arrays of one single run over ``steps`` to its end."""
    edges = np.r_[0.0, np.cumsum(steps.horiz_m)]
    driver = Driver(edges, step_speed_mps, steps.cos_t, accel_max_mps2, dt_s, duty_cycle,
                    stop_every_s)
    return driver.run(np.iinfo(np.int64).max)


def _check_lengths(steps_list, step_speed_list) -> None:
    if len(steps_list) != len(step_speed_list):
        raise ValueError(f"{len(steps_list)} paths but {len(step_speed_list)} speed arrays")


def _yaw_rate(steps, kin: dict, dt_s: float) -> np.ndarray:
    heading = step_headings_rad(steps)[kin["step"]]
    yaw, _ = spread_yaw_rate(heading, heading[0], np.zeros(0),
                             max(1, round(TURN_SPREAD_S / dt_s)), dt_s)
    return yaw


def drive_returns(steps_list, step_speed_list, accel_max_mps2: float, duty_cycle: float,
                  dt_s: float = SAMPLE_DT_S, stop_every_s: float = STOP_EVERY_S) -> list[dict]:
    """The kinematics of many independent single runs, one dict per path: ``Driver.run``'s
    ``v``, ``accel`` and ``step`` and the yaw rate ``yaw_radps`` of ``drive_path`` (what
    ``driven_energies_and_gradients`` reads). They do not depend on the energy model, so a
    caller may keep them across models."""
    _check_lengths(steps_list, step_speed_list)
    kins = [_drive_once(st, v, accel_max_mps2, duty_cycle, dt_s, stop_every_s)
            for st, v in zip(steps_list, step_speed_list)]
    return [{"v": kin["v"], "accel": kin["accel"], "step": kin["step"],
             "yaw_radps": _yaw_rate(st, kin, dt_s)} for st, kin in zip(steps_list, kins)]


def profile_energies_and_gradients(model, steps_list, step_speed_list, accel_max_mps2: float,
                                   conditions: Conditions, dt_s: float = SAMPLE_DT_S,
                                   stop_every_s: float = STOP_EVERY_S
                                   ) -> tuple[np.ndarray, np.ndarray]:
    """Profile energy [J], shape (n,), and its gradient d/d theta, shape (n, k), of many paths:
    per path ``profile_energy(...).total_J`` and ``profile_gradient(...)`` (parameters as
    ``drive_path``, one steps and speed array per path)."""
    kins = drive_returns(steps_list, step_speed_list, accel_max_mps2, conditions.duty_cycle,
                         dt_s, stop_every_s)
    return driven_energies_and_gradients(model, steps_list, kins, conditions, dt_s)


def driven_energies_and_gradients(model, steps_list, kins, conditions: Conditions,
                                  dt_s: float = SAMPLE_DT_S) -> tuple[np.ndarray, np.ndarray]:
    """Energy [J], shape (n,), and gradient d/d theta, shape (n, k), of paths already driven
    (``drive_returns``), from one evaluation of the model's power and Jacobian over all their
    samples (the model's terms are per sample), then reduced path by path as
    ``profile_energy`` / ``profile_gradient`` reduce one path."""
    k = len(model.theta)
    n = len(steps_list)
    if n == 0:
        return np.zeros(0), np.zeros((0, k))
    n_samples = np.array([kin["step"].size for kin in kins])
    bounds = np.r_[0, np.cumsum(n_samples)]
    step_off = np.r_[0, np.cumsum([st.horiz_m.size for st in steps_list])[:-1]]
    j = np.concatenate([kin["step"] for kin in kins]) + np.repeat(step_off, n_samples)
    steps = steps_list[0].concat(steps_list)  # pathcost imports this module: no import back
    yaw = np.concatenate([kin["yaw_radps"] for kin in kins])
    kin = {"step": j, "v": np.concatenate([kin["v"] for kin in kins]),
           "accel": np.concatenate([kin["accel"] for kin in kins])}
    state = drive_state(steps, kin, yaw, conditions.wind_xy_mps, steps.crr[j], conditions)
    power = np.broadcast_to(np.asarray(model.power_W(state), float), j.shape)
    jac = np.broadcast_to(np.asarray(model.power_jacobian(state), float), (j.size, k))
    energy, gradient = np.empty(n), np.empty((n, k))
    for p in range(n):  # the reductions of profile_energy / profile_gradient, path by path
        lo, hi = bounds[p], bounds[p + 1]
        energy[p] = np.cumsum(power[lo:hi])[-1] * dt_s
        gradient[p] = jac[lo:hi].sum(axis=0) * dt_s
    return energy, gradient
