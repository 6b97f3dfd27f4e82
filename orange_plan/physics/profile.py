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

import numpy as np

from orange_plan.physics.pathcost import wrap_pi
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
        sample, ``step`` (sub-step index)."""
        t_out, s_out, v_out, a_out, j_out = [], [], [], [], []
        n_steps, a_dt, dt = len(self.speed), self.a * self.dt, self.dt
        for _ in range(n):
            if self.finished:
                break
            lap_s = self.s % self.length if self.repeat else min(self.s, self.length)
            j = min(bisect_right(self.edges, lap_s) - 1, n_steps - 1)
            target = self._target(j)
            v_new = max(0.0, self.v + min(max(target - self.v, -a_dt), a_dt))
            t_out.append(self.t)
            s_out.append(self.s)
            v_out.append(self.v)
            a_out.append((v_new - self.v) / dt)
            j_out.append(j)
            if self.v > 0 or v_new > 0:
                self.moving += dt
            self.s += 0.5 * (self.v + v_new) * dt * self.cos[j]
            self.v, self.t = v_new, self.t + dt
            if not self.repeat and self.length - self.s <= 1e-6:
                self.arrived = True
            if self.arrived and self.v <= 0 and self.t >= self.moving / self.duty - 1e-9:
                self.finished = True  # at rest at the end, the duty cycle waited out
        return {"t": np.asarray(t_out), "s": np.asarray(s_out), "v": np.asarray(v_out),
                "accel": np.asarray(a_out), "step": np.asarray(j_out, dtype=int)}

    def _target(self, j: int) -> float:
        if self.arrived:
            return 0.0
        cruise = self.speed[j]
        if self.duty < 1.0:
            if self.phase == "move" and self.moving >= self.next_stop:
                self.phase = "brake"
            if self.phase == "brake" and self.v <= 0:
                self.phase = "stop"
            if self.phase == "stop" and self.t >= self.moving / self.duty:
                self.phase, self.next_stop = "move", self.moving + self.every
            if self.phase != "move":
                return 0.0
        if not self.repeat:
            remaining = max(self.length - self.s, 0.0)
            brake = math.sqrt(2 * self.a * remaining) - self.a * self.dt
            return min(cruise, max(brake, CREEP_FRACTION * cruise))
        return cruise


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


def drive_state(steps, kin: dict, yaw_rate_radps, wind_xy_mps, crr, sensor_rate_Hz) -> MotionState:
    """MotionState of driven samples on the sub-steps ``steps`` (``pathcost.Steps``).

    ``wind_xy_mps`` (2,) or (n, 2) and ``crr`` (n,) are passed in because the simulator
    perturbs them (gusts, roughness); the planner passes the mean wind and ``steps.crr``.
    """
    j = kin["step"]
    wind = np.broadcast_to(np.asarray(wind_xy_mps, float), (j.size, 2))
    return MotionState(
        speed_mps=kin["v"], cos_t=steps.cos_t[j], sin_t=steps.sin_t[j], dir_x=steps.dir_x[j],
        dir_y=steps.dir_y[j], wind_x_mps=wind[:, 0], wind_y_mps=wind[:, 1], crr=crr,
        accel_mps2=kin["accel"], yaw_rate_radps=yaw_rate_radps,
        sensor_rate_Hz=np.full(j.size, float(sensor_rate_Hz)),
        surface_code=steps.surface_code[j])


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
        i = np.searchsorted(self.s_m, np.asarray(s_m, float) - 1e-9, side="left")
        i = np.clip(i, 0, self.t_s.size - 1)
        before = np.where(i > 0, self.cumulative_J[np.maximum(i - 1, 0)], 0.0)
        return before, self.t_s[i]


def drive_path(steps, step_speed_mps, accel_max_mps2: float, duty_cycle: float,
               wind_xy_mps=(0.0, 0.0), sensor_rate_Hz: float = 0.0, dt_s: float = SAMPLE_DT_S,
               stop_every_s: float = STOP_EVERY_S) -> tuple[dict, MotionState]:
    """Drive sub-steps once with ``Driver``: the samples (``Driver.run``'s arrays) and their
    MotionState (mean wind, the map's crr, heading changes spread over ``TURN_SPREAD_S``).

    Parameters
    ----------
    steps : ``pathcost.Steps`` of the path, in order (at least one of positive length)
    step_speed_mps : cruise speed per sub-step [m/s]
    accel_max_mps2 : acceleration limit [m/s^2]; duty_cycle : D [-]
    wind_xy_mps : mean wind [m/s]; sensor_rate_Hz : [Hz]
    dt_s : time step [s]; stop_every_s : moving time between duty-cycle stops [s]
    """
    edges = np.r_[0.0, np.cumsum(steps.horiz_m)]
    driver = Driver(edges, step_speed_mps, steps.cos_t, accel_max_mps2, dt_s, duty_cycle,
                    stop_every_s)
    chunks = []
    while not driver.finished:
        chunks.append(driver.run(100_000))
    kin = {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}
    heading = step_headings_rad(steps)[kin["step"]]
    yaw, _ = spread_yaw_rate(heading, heading[0], np.zeros(0), max(1, round(TURN_SPREAD_S / dt_s)),
                             dt_s)
    return kin, drive_state(steps, kin, yaw, wind_xy_mps, steps.crr[kin["step"]], sensor_rate_Hz)


def profile_energy(model, steps, step_speed_mps, accel_max_mps2: float, duty_cycle: float,
                   wind_xy_mps=(0.0, 0.0), sensor_rate_Hz: float = 0.0,
                   dt_s: float = SAMPLE_DT_S, stop_every_s: float = STOP_EVERY_S) -> ProfileEnergy:
    """Energy of the profile ``drive_path`` drives (parameters as there).

    Notes
    -----
    ``E = sum_k P(state_k) dt`` with ``P`` = ``EnergyModel.power_W`` (time domain: inertia,
    regen and the rate terms all apply): the energy the simulator draws on the same path with
    no truth-only effects.
    """
    kin, state = drive_path(steps, step_speed_mps, accel_max_mps2, duty_cycle, wind_xy_mps,
                            sensor_rate_Hz, dt_s, stop_every_s)
    power = np.broadcast_to(np.asarray(model.power_W(state), float), kin["t"].shape)
    return ProfileEnergy(kin["t"], kin["s"], np.cumsum(power) * dt_s, dt_s)


def profile_gradient(model, steps, step_speed_mps, accel_max_mps2: float, duty_cycle: float,
                     wind_xy_mps=(0.0, 0.0), sensor_rate_Hz: float = 0.0,
                     dt_s: float = SAMPLE_DT_S, stop_every_s: float = STOP_EVERY_S) -> np.ndarray:
    """d(profile energy)/d theta, shape (k,): ``sum_k dP/dtheta(state_k) dt`` (reserve sizing;
    ``gradient @ theta`` is the profile energy for models without regen)."""
    _, state = drive_path(steps, step_speed_mps, accel_max_mps2, duty_cycle, wind_xy_mps,
                          sensor_rate_Hz, dt_s, stop_every_s)
    return model.power_jacobian(state).sum(axis=0) * dt_s
