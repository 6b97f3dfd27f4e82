"""Mission simulator: drive a route under a truth model and produce a recording.

The power at every sample is the scenario model's own ``EnergyModel.power_W`` evaluated on
the simulated motion state (no physics is re-typed here). The simulator adds only the
truth-only effects of ``sim.truth.Truth``: coefficient overrides, wind gusts, a payload change,
terrain roughness, battery ageing, recording noise and the duty-cycle stop cadence. The motion
is the planner's own speed profile (``physics.profile.Driver``: ramps at ``accel_max_mps2``,
duty-cycle stops, at rest at both ends with the duty cycle waited out at the end), so a plan's
energy and the simulated draw of the same path under the same model agree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from scipy.signal import lfilter

from orange_plan.errors import InputError, close_match_hint
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.model_builder import with_payload
from orange_plan.physics.pathcost import subdivide
from orange_plan.physics.profile import (
    SAMPLE_DT_S,
    TURN_SPREAD_S,
    Driver,
    drive_state,
    spread_yaw_rate,
    step_headings_rad,
)
from orange_plan.physics.wind import wind_speed_and_from
from orange_plan.sim.route import Route
from orange_plan.sim.truth import Truth, Wind
from orange_plan.telemetry.derive import duration_s

if TYPE_CHECKING:
    from orange_plan.context import Context

MAX_RATE_HZ = 1000.0
"""Highest recording rate: beyond it a long run's table no longer fits in memory (1e5 Hz
took minutes and 1.4 GB for a short route) and no battery logger samples faster."""

CHUNK_S = 600.0
"""Simulated time per vectorised power evaluation (depletion is checked per chunk) [s]."""


@dataclass(frozen=True)
class SimResult:
    """A simulated run.

    Attributes
    ----------
    frame : the recording (recording columns (docs/formats.md))
    energy_J : true battery energy drawn (without recording noise) [J]
    energy_available_J : the truth's usable energy (scenario E_avail x capacity_factor) [J]
    distance_m : distance travelled along the path [m]
    duration_s : the recording's duration, first to last sample (``telemetry.derive``) [s]
    moving_time_s : time with non-zero speed [s]
    depleted : the run stopped because the usable energy was spent
    laps : number of route laps driven (fractional) [-]
    speeds_clipped : route vertices whose commanded speed lay outside [v_min_mps, v_max_mps]
        and was clipped to that interval
    """

    frame: pd.DataFrame
    energy_J: float
    energy_available_J: float
    distance_m: float
    duration_s: float
    moving_time_s: float
    depleted: bool
    laps: float
    speeds_clipped: int = 0

    def summary(self) -> dict:
        """The scalar results (for ``--json``)."""
        return {k: getattr(self, k) for k in (
            "energy_J", "energy_available_J", "distance_m", "duration_s", "moving_time_s",
            "depleted", "laps", "speeds_clipped")} | {"samples": len(self.frame)}


def truth_model(model: EnergyModel, truth: Truth) -> EnergyModel:
    """The scenario model with the truth's coefficient overrides.

    Raises
    ------
    InputError
        An override names a coefficient the model does not have.
    """
    unknown = [k for k in truth.coefficients if k not in model.names]
    if unknown:
        raise InputError(f"truth [coefficients] names '{unknown[0]}', not a coefficient of this "
                         f"model (have {', '.join(model.names)})"
                         + close_match_hint(unknown[0], model.names))
    return model.with_theta(truth.coefficients)


def _ou(rng, n: int, dt: float, std: float, tau: float, start: np.ndarray) -> np.ndarray:
    """Ornstein-Uhlenbeck samples (n, 2) continuing from ``start`` (2,), exact discretisation."""
    phi = math.exp(-dt / tau)
    noise = rng.standard_normal((n, 2)) * std * math.sqrt(1 - phi**2)
    return np.stack([lfilter([1.0], [1.0, -phi], noise[:, i], zi=[phi * start[i]])[0]
                     for i in range(2)], axis=1)


def _roughness(rng, length_m: float, std: float, corr_m: float):
    """A spatially correlated crr perturbation along a lap: (grid_m, values)."""
    grid = np.arange(0.0, length_m + 0.25, 0.25)
    if std == 0:
        return grid, np.zeros_like(grid)
    phi = math.exp(-0.25 / corr_m)
    noise = rng.standard_normal(grid.size) * std * math.sqrt(1 - phi**2)
    noise[0] = rng.standard_normal() * std
    return grid, lfilter([1.0], [1.0, -phi], noise)


def simulate(ctx: Context, route: Route, truth: Truth | None = None, seed: int = 0,
             sample_rate_Hz: float = 1.0 / SAMPLE_DT_S, to_depletion: bool = False,
             max_duration_s: float = 172_800.0, energy_start_J: float = 0.0) -> SimResult:
    """Drive ``route`` in the scenario's world under ``truth`` and record it.

    Parameters
    ----------
    ctx : Context (scenario, world, model)
    route : the route; vertices without a speed get the scenario's simplified-range v_opt;
        commanded speeds are clipped to [v_min_mps, v_max_mps] (counted in ``speeds_clipped``)
    truth : truth-only effects (default none: the truth is the planning model)
    seed : random seed (gusts, roughness, noise)
    sample_rate_Hz : recording rate [Hz]
    to_depletion : repeat the route (closed, or out and back) until the truth's usable energy
        is spent; else drive it once
    max_duration_s : hard stop on mission time [s]
    energy_start_J : true energy already drawn from the battery when this drive starts [J]
        (a mission flown as several drives): ``soc`` and depletion count it, ``energy_J``
        does not

    Returns
    -------
    SimResult

    Notes
    -----
    Power per sample: ``truth_model.power_W(state)`` with the true wind (mean + OU gusts), the
    true crr (map + roughness) and the payload phase; the recorded ``power_W`` adds white
    noise. Energy drawn is ``sum P dt`` (rectangle rule over the samples).
    """
    truth = truth or Truth()
    if not (0 < sample_rate_Hz <= MAX_RATE_HZ):
        raise InputError(f"sample_rate_Hz (--rate-hz) = {sample_rate_Hz!r} must be in "
                         f"(0, {MAX_RATE_HZ:g}] Hz")
    if not (math.isfinite(energy_start_J) and energy_start_J >= 0):
        raise InputError(f"energy_start_J = {energy_start_J!r} must be a finite number >= 0 J")
    if not (0 < max_duration_s < math.inf):
        raise InputError(f"max_duration_s (--max-duration-s) = {max_duration_s!r} must be a "
                         "positive number of seconds")
    scenario, world = ctx.scenario, ctx.world
    world.check_route(route.xy_m, route.source)
    route = route.with_default_speed(ctx.cruise_speed_mps)
    lap = route.lap() if to_depletion else route
    rng = np.random.default_rng(seed)
    dt = 1.0 / sample_rate_Hz

    steps = subdivide(world, lap.xy_m[:-1], lap.xy_m[1:])
    edges = np.r_[0.0, np.cumsum(steps.horiz_m)]
    step_heading = step_headings_rad(steps)
    # One rule for commanded speeds: clip to the robot's [v_min, v_max], and count it.
    v_lo, v_hi = scenario.robot.v_min_mps, scenario.robot.v_max_mps
    clipped = int(np.count_nonzero((route.speed_mps < v_lo) | (route.speed_mps > v_hi)))
    speed = np.clip(lap.speed_mps[steps.segment], v_lo, v_hi)
    driver = Driver(edges, speed, steps.cos_t, scenario.robot.accel_max_mps2, dt,
                    ctx.conditions.duty_cycle, truth.stop_every_s, to_depletion)
    vertex_s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(lap.xy_m, axis=0).T))]
    rough_grid, rough = _roughness(rng, float(edges[-1]), truth.roughness_crr_std,
                                   truth.roughness_length_m)

    base = truth_model(ctx.model, truth)
    loaded = with_payload(base, scenario.robot.mass_kg, truth.payload_kg)
    # The context's conditions give the mean wind unless the truth has its own; gusts are
    # truth-only (none without a truth wind).
    wind = truth.wind or Wind()
    mean_wind = wind.mean_xy_mps if truth.wind else ctx.conditions.wind_xy_mps
    gust = rng.standard_normal(2) * wind.gust_std_mps
    e_avail = scenario.battery.usable_J * truth.capacity_factor
    heading0 = step_heading[0]
    carry, k_turn = np.zeros(0), max(1, round(TURN_SPREAD_S / dt))

    chunks, used, depleted = [], float(energy_start_J), False
    per_chunk = max(1, round(CHUNK_S / dt))
    while not driver.finished and driver.t < max_duration_s and not depleted:
        kin = driver.run(min(per_chunk, max(1, round((max_duration_s - driver.t) / dt))))
        if kin["t"].size == 0:
            break
        j = kin["step"]
        s_lap = kin["s"] % edges[-1] if to_depletion else np.minimum(kin["s"], edges[-1])
        gusts = _ou(rng, j.size, dt, wind.gust_std_mps, wind.gust_tau_s, gust)
        gust = gusts[-1]
        wind_xy = np.asarray(mean_wind) + gusts
        heading = step_heading[j]
        yaw, carry = spread_yaw_rate(heading, heading0, carry, k_turn, dt)
        heading0 = heading[-1]
        crr = np.clip(steps.crr[j] + np.interp(s_lap, rough_grid, rough), 0.0, 1.0)
        # the truth's drift follows the clock; planning's is held at its worst (Conditions)
        state = drive_state(steps, kin, yaw, wind_xy, crr, ctx.conditions).with_(
            elapsed_s=kin["t"])
        carrying = kin["t"] >= truth.payload_from_s if truth.payload_kg else np.zeros(j.size, bool)
        power = base.power_W(state)
        if carrying.any():  # the loaded model only where the payload is on board
            power = np.where(carrying, loaded.power_W(state), power)
        cum = used + np.cumsum(power) * dt
        if to_depletion and cum[-1] >= e_avail:
            n = int(np.searchsorted(cum, e_avail)) + 1
            depleted = True
        else:
            n = j.size
        used = float(cum[n - 1])
        chunks.append(_columns(kin, s_lap, vertex_s, lap, world, state, power, carrying,
                               truth, wind, cum, e_avail, n))
    frame = pd.concat([pd.DataFrame(c) for c in chunks], ignore_index=True)
    laps = float(frame.pop("_s").iloc[-1] / edges[-1])
    _add_noise(frame, rng, truth)
    distance = float(np.sum(frame["v_mps"]) * dt)
    return SimResult(frame, used - float(energy_start_J), e_avail, distance,
                     duration_s(frame["t_s"]), float(np.count_nonzero(frame["v_mps"] > 0) * dt), depleted, laps, clipped)


def _columns(kin, s_lap, vertex_s, lap, world, state, power, carrying, truth, wind, cum,
             e_avail, n) -> dict:
    x = np.interp(s_lap, vertex_s, lap.xy_m[:, 0])
    y = np.interp(s_lap, vertex_s, lap.xy_m[:, 1])
    names = world.map.surface_names
    code = np.asarray(state.surface_code)
    cols = {
        "t_s": kin["t"], "x_m": x, "y_m": y, "z_m": world.elevation_at(x, y),
        "v_mps": kin["v"], "yaw_rate_radps": state.yaw_rate_radps, "accel_mps2": kin["accel"],
        "power_W": power, "soc": np.clip(1.0 - cum / e_avail, 0.0, 1.0),
        "payload_kg": np.where(carrying, truth.payload_kg, 0.0),
        "sensor_rate_Hz": state.sensor_rate_Hz,
        "surface": np.array([*names, world.default_surface_name], dtype=object)[code],
        "_s": kin["s"],
    }
    if wind.recorded:
        wx, wy = np.asarray(state.wind_x_mps), np.asarray(state.wind_y_mps)
        cols["wind_mps"], cols["wind_from_deg"] = wind_speed_and_from(wx, wy)
    return {k: np.asarray(v)[:n] for k, v in cols.items()}


def _add_noise(frame: pd.DataFrame, rng, truth: Truth) -> None:
    if truth.power_std_W:
        frame["power_W"] += rng.standard_normal(len(frame)) * truth.power_std_W
    if truth.position_std_m:
        frame["x_m"] += rng.standard_normal(len(frame)) * truth.position_std_m
        frame["y_m"] += rng.standard_normal(len(frame)) * truth.position_std_m
