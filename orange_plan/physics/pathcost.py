"""Energy of straight segments and polylines over a World (the reference model's path integral).

Terrain that varies along a segment is integrated in sub-steps no longer than 0.5 m or half
an elevation cell, with the no-recovery ``max(0, .)`` applied per sub-step; turning energy is
charged at every interior vertex. Everything is vectorised over many segments at once (the
planner weights a whole roadmap in one call). ``path_energy`` with the robot's acceleration
limit gives instead the energy of the speed profile the robot drives (``physics.profile``),
which is what planners report.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orange_plan.errors import InputError
from orange_plan.physics.conditions import Conditions
from orange_plan.physics.model import EnergyModel, SegmentEnergy
from orange_plan.physics.ops import wrap_pi
from orange_plan.physics.profile import profile_energy
from orange_plan.physics.state import MotionState

MAX_STEP_M = 0.5
"""Longest integration sub-step [m]; shortened to half a raster cell if smaller."""


@dataclass(frozen=True)
class Steps:
    """Straight sub-steps of many segments (flat arrays, one entry per sub-step).

    Attributes
    ----------
    segment : index of the segment each sub-step belongs to
    length_m : 3-D length L [m]; horiz_m : horizontal length d [m]; dz_m : rise [m]
    dir_x, dir_y : unit horizontal direction [-]
    crr : rolling coefficient at the sub-step midpoint [-]
    surface_code : surface index at the midpoint, -1 for default ground
    n_segments : number of input segments
    """

    segment: np.ndarray
    length_m: np.ndarray
    horiz_m: np.ndarray
    dz_m: np.ndarray
    dir_x: np.ndarray
    dir_y: np.ndarray
    crr: np.ndarray
    surface_code: np.ndarray
    n_segments: int

    @property
    def cos_t(self) -> np.ndarray:
        """Cosine of each sub-step's grade (1 for a zero-length step) [-]."""
        return np.where(self.length_m > 0, self.horiz_m / self._safe_length_m, 1.0)

    @property
    def sin_t(self) -> np.ndarray:
        """Sine of each sub-step's grade, uphill positive (0 for a zero-length step) [-]."""
        return np.where(self.length_m > 0, self.dz_m / self._safe_length_m, 0.0)

    @property
    def _safe_length_m(self) -> np.ndarray:
        return np.where(self.length_m > 0, self.length_m, 1.0)

    @classmethod
    def concat(cls, steps_list) -> Steps:
        """The sub-steps of several paths one after the other (segments numbered on), as
        plain Steps whatever their kind (``steps.concat(...)`` serves modules that cannot
        import this one)."""
        offsets = np.r_[0, np.cumsum([st.n_segments for st in steps_list])[:-1]]
        arrays = {name: np.concatenate([np.asarray(getattr(st, name)) for st in steps_list])
                  for name in ("length_m", "horiz_m", "dz_m", "dir_x", "dir_y", "crr",
                               "surface_code")}
        segment = np.concatenate([st.segment + off for st, off in zip(steps_list, offsets)])
        return Steps(segment=segment, n_segments=int(sum(st.n_segments for st in steps_list)),
                     **arrays)

    def per_step(self, per_segment) -> np.ndarray:
        """A per-segment (or scalar) value repeated onto every sub-step of its segment."""
        return np.broadcast_to(np.asarray(per_segment, float), (self.n_segments,))[self.segment]

    def state(self, speed_mps, conditions: Conditions) -> MotionState:
        """MotionState of every sub-step at per-segment (or scalar) speeds."""
        speed = self.per_step(speed_mps)
        return MotionState(
            speed_mps=speed,
            cos_t=self.cos_t,
            sin_t=self.sin_t,
            dir_x=self.dir_x,
            dir_y=self.dir_y,
            wind_x_mps=conditions.wind_xy_mps[0],
            wind_y_mps=conditions.wind_xy_mps[1],
            crr=self.crr,
            sensor_rate_Hz=conditions.sensor_rate_Hz,
            surface_code=self.surface_code,
            channels=conditions.channels,
        )

    def per_segment(self, values) -> np.ndarray:
        """Sum a per-sub-step array into one value per segment."""
        return np.bincount(self.segment, weights=values, minlength=self.n_segments)


def max_step_m(world) -> float:
    """Sub-step length for a world: 0.5 m or half a raster cell, whichever is shorter [m]."""
    raster = world.map.elevation
    return MAX_STEP_M if raster is None else min(MAX_STEP_M, raster.cell_m / 2)


def subdivide(world, start_xy, end_xy, step_m: float | None = None, terrain=None) -> Steps:
    """Cut segments ``start_xy[i] -> end_xy[i]`` (shape (n, 2)) into straight sub-steps.

    ``terrain``: optional object with ``crr_at`` and ``surface_code_at`` used instead of the
    world's exact shapely queries (e.g. ``world.rasters.TerrainRasters`` for roadmap weights).
    """
    surfaces = world if terrain is None else terrain
    a = np.atleast_2d(np.asarray(start_xy, float))
    b = np.atleast_2d(np.asarray(end_xy, float))
    if a.shape != b.shape or a.shape[-1] != 2:
        raise InputError(f"segment endpoints must both have shape (n, 2), got {a.shape}, {b.shape}")
    step = max_step_m(world) if step_m is None else step_m
    delta = b - a
    horiz = np.hypot(delta[:, 0], delta[:, 1])
    n_sub = np.maximum(1, np.ceil(horiz / step).astype(int))
    seg = np.repeat(np.arange(len(a)), n_sub)
    first = np.cumsum(n_sub) - n_sub
    k = np.arange(seg.size) - first[seg]
    t0, t1 = k / n_sub[seg], (k + 1) / n_sub[seg]
    p0 = a[seg] + delta[seg] * t0[:, None]
    p1 = a[seg] + delta[seg] * t1[:, None]
    mid = 0.5 * (p0 + p1)
    z = world.elevation_at(p0[:, 0], p0[:, 1])
    z1 = world.elevation_at(p1[:, 0], p1[:, 1])
    d = horiz[seg] / n_sub[seg]
    dz = z1 - z
    safe = np.where(horiz > 0, horiz, 1.0)
    ux, uy = delta[:, 0] / safe, delta[:, 1] / safe
    return Steps(
        segment=seg,
        length_m=np.hypot(d, dz),
        horiz_m=d,
        dz_m=dz,
        dir_x=np.where(horiz > 0, ux, 1.0)[seg],
        dir_y=np.where(horiz > 0, uy, 0.0)[seg],
        crr=surfaces.crr_at(mid[:, 0], mid[:, 1]),
        surface_code=surfaces.surface_code_at(mid[:, 0], mid[:, 1]),
        n_segments=len(a),
    )


def heading_changes_rad(path_xy) -> np.ndarray:
    """|heading change| at each interior vertex of a polyline, shape (n_vertices - 2,) [rad]."""
    p = np.asarray(path_xy, float)
    delta = np.diff(p, axis=0)
    heading = np.arctan2(delta[:, 1], delta[:, 0])
    # a repeated vertex has no heading of its own: it keeps the one before (or, leading, the
    # first real one), so it is not counted as a turn to heading 0
    moving = np.hypot(delta[:, 0], delta[:, 1]) > 0
    if moving.any() and not moving.all():
        last = np.maximum.accumulate(np.where(moving, np.arange(moving.size), -1))
        last[last < 0] = np.argmax(moving)
        heading = heading[last]
    return np.abs(wrap_pi(np.diff(heading)))


def segments_energy(
    model: EnergyModel,
    world,
    start_xy,
    end_xy,
    speed_mps,
    conditions: Conditions,
    steps: Steps | None = None,
) -> SegmentEnergy:
    """Energy of each straight segment (no turning), arrays of shape (n,) [J] and times [s]."""
    steps = subdivide(world, start_xy, end_xy) if steps is None else steps
    speed = np.broadcast_to(np.asarray(speed_mps, float), (steps.n_segments,))
    if np.any(speed <= 0):
        raise InputError("speed_mps must be > 0 on every segment")
    state = steps.state(speed, conditions)
    e = model.segment_energy(state, steps.length_m, conditions.duty_cycle)
    total = steps.per_segment
    return SegmentEnergy(
        ancillary_J=total(e.ancillary_J),
        traversal_J=total(e.traversal_J),
        turning_J=np.zeros(steps.n_segments),
        moving_time_s=total(e.moving_time_s),
        mission_time_s=total(e.mission_time_s),
    )


@dataclass(frozen=True)
class PathEnergy:
    """Energy along a polyline (battery side).

    Attributes
    ----------
    segments : reference-model per-segment energies at cruise speed throughout (turning charged to the
        segment leaving the vertex): the reference figure
    cumulative_J : energy used on arrival at each vertex, shape (n_vertices,) [J]; at the last
        vertex the whole path's energy
    cumulative_time_s : mission time at each vertex, shape (n_vertices,) [s]

    With a speed profile (``path_energy(..., accel_max_mps2=a)``) the cumulative figures are
    those of the driven profile: ramps at ``a``, duty-cycle stops, at rest at both ends, the
    duty cycle waited out at the end (``physics.profile``); without one they are the reference model's
    sums of ``segments``.
    """

    segments: SegmentEnergy
    cumulative_J: np.ndarray
    cumulative_time_s: np.ndarray

    @property
    def total_J(self) -> float:
        return float(self.cumulative_J[-1])

    @property
    def duration_s(self) -> float:
        return float(self.cumulative_time_s[-1])

    @property
    def reference_J(self) -> float:
        """The reference-model figure: cruise speed throughout, stops through the duty cycle [J]."""
        return float(np.sum(self.segments.total_J))

    @property
    def profile_J(self) -> float:
        """Energy of the speed profile on top of the reference-model figure (0 without a profile) [J]:
        the longer moving time of speeding up and slowing down, inertia and regen if modelled."""
        return self.total_J - self.reference_J


def path_energy(
    model: EnergyModel,
    world,
    path_xy,
    speed_mps,
    conditions: Conditions,
    accel_max_mps2: float | None = None,
) -> PathEnergy:
    """Energy of a polyline at per-segment (or scalar) speeds, turning at interior vertices.

    Parameters
    ----------
    model : the energy model; world : the World
    path_xy : vertices (n, 2) [m]
    speed_mps : cruise speed per segment (n - 1,) or scalar [m/s]
    conditions : duty cycle, sensor rate and wind (``physics.conditions``)
    accel_max_mps2 : the robot's acceleration limit [m/s^2]. Given, the energy is that of the
        speed profile the robot drives (``physics.profile``: what the simulator draws on this
        path under this model); None gives the reference-model figure, cruise speed
        throughout. Planners pass it: a plan must not be optimistic.

    Notes
    -----
    Reference: per sub-step ``P_anc L / (v D) + max(0, F) L``, plus
    ``turn_J_per_rad |heading change|`` per interior vertex. Profile:
    ``sum_k P(state_k) dt`` over the driven samples, ``P`` the model's time-domain power.
    """
    p = np.asarray(path_xy, float)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) < 2:
        raise InputError(f"a path needs at least two (x, y) vertices, got shape {p.shape}")
    steps = subdivide(world, p[:-1], p[1:])
    seg = segments_energy(model, world, None, None, speed_mps, conditions, steps=steps)
    turning = np.zeros(len(p) - 1)
    if len(p) > 2:
        turning[1:] = model.turning_energy_J(heading_changes_rad(p))
    seg = SegmentEnergy(seg.ancillary_J, seg.traversal_J, turning, seg.moving_time_s,
                        seg.mission_time_s)
    if accel_max_mps2 is None or not np.any(steps.horiz_m > 0):
        cumulative = np.r_[0.0, np.cumsum(seg.total_J)]
        time = np.r_[0.0, np.cumsum(seg.mission_time_s)]
        return PathEnergy(seg, cumulative, time)
    drive = profile_energy(model, steps, steps.per_step(speed_mps), accel_max_mps2, conditions)
    vertex_s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(p, axis=0).T))]
    cumulative, time = drive.at_arclength(vertex_s)
    cumulative[-1], time[-1] = drive.total_J, drive.duration_s  # the final wait included
    return PathEnergy(seg, cumulative, time)


def segments_energy_jacobian(
    model: EnergyModel, world, steps: Steps, speed_mps, conditions: Conditions
) -> np.ndarray:
    """d(energy of each segment)/d theta, shape (n_segments, n_coefficients) [J per unit].

    With the model's covariance, ``model.energy_variance_J2(jac.sum(0))`` is the variance of a
    path's energy: the basis of a reserve sized by confidence (docs/guide/plan.md).
    """
    speed = np.broadcast_to(np.asarray(speed_mps, float), (steps.n_segments,))
    state = steps.state(speed, conditions)
    jac = model.segment_energy_jacobian(state, steps.length_m, conditions.duty_cycle)
    return np.stack([steps.per_segment(jac[:, k]) for k in range(jac.shape[1])], axis=-1)
