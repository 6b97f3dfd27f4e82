"""The interpreted ``physics.profile.Driver`` as it was before its loop was compiled (numba):
the test oracle of the compiled kinematics (same samples, bit for bit). Not used by the package.
"""

from __future__ import annotations

import math
from bisect import bisect_right

import numpy as np

from orange_plan.physics.profile import CREEP_FRACTION, STOP_EVERY_S


class ReferenceDriver:
    """``physics.profile.Driver`` interpreted (its Parameters and Notes hold here too)."""

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
