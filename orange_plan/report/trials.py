"""What the report's experiments share: truth draws, runs to depletion, range estimates.

Range estimation error (the paper's measure, ``sim.ranges.accuracy_pct``)::

    error_pct = 100 |d_est - d_true| / d_true,     accuracy_pct = 100 - error_pct

``d_true`` is the distance the simulated truth actually covered before its usable energy was
spent (``simulate(..., to_depletion=True)``); ``d_est`` is the estimate made before (offline)
or during (online) that run.

A truth is drawn per trial from a ``Variation``: a systematic bias (the robot is not its
datasheet: the a-priori scenario values are off by a fixed factor per coefficient), a
trial-to-trial spread of every coefficient and of the battery's usable energy, terrain
roughness, wind, and sensor noise on the recorded power. The report prints each experiment's
variation beside its table.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace

import numpy as np

from orange_plan.context import Context
from orange_plan.identify.calibrate import Calibrator
from orange_plan.identify.online import OnlineEstimator, stream
from orange_plan.sim.ranges import accuracy_pct, offline_range_m
from orange_plan.sim.route import Route
from orange_plan.sim.simulator import SimResult, simulate
from orange_plan.sim.truth import truth_from_dict
from orange_plan.telemetry.recording import recording_from_frame
from orange_plan.telemetry.state import recording_state


@dataclass(frozen=True)
class Variation:
    """Truth-only effects of one experiment (see the module docstring).

    Attributes
    ----------
    bias : coefficient name -> true / scenario multiplier, the same in every trial [-]
    coefficient_rel_sd : per-trial relative sd of every coefficient's multiplier [-]
    capacity_factor : mean true usable energy / the scenario's [-]
    capacity_rel_sd : its per-trial relative sd [-]
    power_std_W : white noise on the recorded power [W]
    roughness_crr_std : spatially correlated crr perturbation (ground robots) [-]
    wind_mean_mps, wind_from_deg : true mean wind; None keeps the scenario's [m/s], [deg]
    wind_sd_mps, wind_from_sd_deg : its per-trial spread [m/s], [deg]
    gust_std_mps, gust_tau_s : Ornstein-Uhlenbeck gusts [m/s], [s]
    """

    bias: dict[str, float] = field(default_factory=dict)
    coefficient_rel_sd: float = 0.05
    capacity_factor: float = 1.0
    capacity_rel_sd: float = 0.03
    power_std_W: float = 0.3
    roughness_crr_std: float = 0.0
    wind_mean_mps: float | None = None
    wind_from_deg: float = 0.0
    wind_sd_mps: float = 0.0
    wind_from_sd_deg: float = 0.0
    gust_std_mps: float = 0.0
    gust_tau_s: float = 5.0

    def describe(self) -> str:
        """One line for the report: what the truth does differently from the scenario."""
        parts = [f"{name} x{factor:g}" for name, factor in self.bias.items()]
        parts.append(f"every coefficient x N(1, {self.coefficient_rel_sd:g}) per trial")
        parts.append(f"usable energy x {self.capacity_factor:g} (sd {self.capacity_rel_sd:g})")
        if self.roughness_crr_std:
            parts.append(f"crr roughness sd {self.roughness_crr_std:g}")
        if self.wind_mean_mps is not None:
            parts.append(f"wind {self.wind_mean_mps:g} +- {self.wind_sd_mps:g} m/s from "
                         f"{self.wind_from_deg:g} +- {self.wind_from_sd_deg:g} deg, gusts "
                         f"{self.gust_std_mps:g} m/s (tau {self.gust_tau_s:g} s), not recorded")
        parts.append(f"power sensor noise {self.power_std_W:g} W")
        return "; ".join(parts)


def draw_truth(ctx: Context, variation: Variation, rng: np.random.Generator,
               extra_bias: dict[str, float] | None = None) -> dict:
    """One trial's truth as a TRUTH.toml-shaped dict (``sim.truth.truth_from_dict``).

    ``extra_bias`` multiplies on top of ``variation.bias`` (e.g. wear after n missions).
    Multipliers are drawn per coefficient and truncated at zero: a coefficient never flips
    sign.
    """
    bias = dict(variation.bias)
    for name, factor in (extra_bias or {}).items():
        bias[name] = bias.get(name, 1.0) * factor
    coefficients = {}
    for name in ctx.model.names:
        value = ctx.model.coefficient(name)
        spread = 1.0 + variation.coefficient_rel_sd * rng.standard_normal()
        coefficients[name] = value * bias.get(name, 1.0) * max(spread, 0.0)
    capacity = variation.capacity_factor * (1.0 + variation.capacity_rel_sd
                                            * rng.standard_normal())
    truth: dict = {"coefficients": coefficients,
                   "battery": {"capacity_factor": max(capacity, 0.05)},
                   "noise": {"power_std_W": variation.power_std_W}}
    if variation.roughness_crr_std:
        truth["terrain"] = {"roughness_crr_std": variation.roughness_crr_std,
                            "roughness_length_m": 2.0}
    if variation.wind_mean_mps is not None:
        mean = variation.wind_mean_mps + variation.wind_sd_mps * rng.standard_normal()
        truth["wind"] = {
            "mean_mps": max(mean, 0.0),
            "from_deg": (variation.wind_from_deg
                         + variation.wind_from_sd_deg * rng.standard_normal()) % 360.0,
            "gust_std_mps": variation.gust_std_mps, "gust_tau_s": variation.gust_tau_s,
            "recorded": False}
    return truth


LOGGER_HZ = 2.0
"""Recording rate of runs whose log is fitted or streamed (calibration drives, the wear
missions): a battery logger's rate, and five times fewer samples to fit than the
simulator's 10 Hz default [Hz]."""


def run_to_depletion(ctx: Context, route: Route, truth: dict, seed: int,
                     sample_rate_Hz: float = 10.0) -> SimResult:
    """Drive ``route`` round and round under ``truth`` until its usable energy is spent."""
    return simulate(ctx, route, truth_from_dict(truth, "report truth"), seed=seed,
                    sample_rate_Hz=sample_rate_Hz, to_depletion=True)


def with_duty_cycle(ctx: Context, duty_cycle: float) -> Context:
    """The same robot and world flown at another duty cycle D."""
    mission = replace(ctx.scenario.mission, duty_cycle=duty_cycle)
    return ctx.with_scenario(replace(ctx.scenario, mission=mission))


def with_belief(ctx: Context, model=None, energy_factor: float = 1.0,
                extra_cycles: float = 0.0) -> Context:
    """What the estimator believes: ``model`` (default the scenario's), the scenario's usable
    energy times ``energy_factor`` (a measured state of health), ``extra_cycles`` more charge
    cycles on the battery (its nominal fade, Eq. 3, applies to them).

    The usable energy is linear in ``rated_energy_Wh``, so the factor goes there.
    """
    battery = ctx.scenario.battery
    battery = replace(battery, rated_energy_Wh=battery.rated_energy_Wh * energy_factor,
                      cycles=battery.cycles + extra_cycles)
    scenario = replace(ctx.scenario, battery=battery)
    return replace(ctx.with_scenario(scenario), model=ctx.model if model is None else model)


def course_range_m(ctx: Context, route: Route) -> float:
    """Offline range on the course (Eq. 11 with the path integral taken on ``route`` at its
    commanded speeds; on a flat course without turning costs this is Eq. 6) [m]."""
    return offline_range_m(ctx, route)


def course(ctx: Context, xy_m) -> Route:
    """A closed (or out-and-back) course at the scenario's cruise speed (v_opt)."""
    xy = np.asarray(xy_m, float)
    return Route(xy, np.full(len(xy), ctx.cruise_speed_mps), "report course")


CALIBRATION_RUNS = 3
"""Calibration runs to depletion per robot: one run's own draw (its battery, its day) would
otherwise bias every estimate made from it."""


def calibrate_on(ctx: Context, sims: list[SimResult], source: str) -> tuple[object, float]:
    """A priori calibration from runs to depletion: the coefficients fitted on their
    recordings (``identify.calibrate.Calibrator``) and the measured state of health (mean
    energy a run drew / the scenario's usable energy).

    Returns (fitted EnergyModel, energy factor).
    """

    recs = [recording_from_frame(sim.frame, f"{source} {k}") for k, sim in enumerate(sims)]
    fitted = Calibrator().fit(recs, ctx).model_
    return fitted, float(np.mean([r.energy_J for r in recs])) / ctx.scenario.battery.usable_J


def calibration_runs(ctx: Context, route: Route, variation: Variation, rng,
                     extra_bias: dict[str, float] | None = None) -> list[SimResult]:
    """``CALIBRATION_RUNS`` runs to depletion, each a fresh truth draw of the experiment."""
    return [run_to_depletion(ctx, route, draw_truth(ctx, variation, rng, extra_bias),
                             int(rng.integers(2**31)), LOGGER_HZ)
            for _ in range(CALIBRATION_RUNS)]


def advance(tick, items: int = 1) -> None:
    """Advance a progress bar (``progress.bar``'s tick, or None when none is shown)."""
    for _ in range(items if tick else 0):
        tick()


def error_pct(d_est_m: float, d_true_m: float) -> float:
    """Range estimation error ``100 |d_est - d_true| / d_true`` [%]."""
    return 100.0 - accuracy_pct(d_est_m, d_true_m)


@dataclass(frozen=True)
class Stat:
    """Mean and sample standard deviation of one measure over trials."""

    mean: float
    sd: float
    n: int

    def text(self, digits: int = 1) -> str:
        if self.n < 2 or not math.isfinite(self.sd):
            return f"{self.mean:.{digits}f}"
        return f"{self.mean:.{digits}f} ± {self.sd:.{digits}f}"


def stat(values) -> Stat:
    """Mean and sample sd (ddof 1; NaN for a single value)."""
    v = np.asarray(list(values), float)
    sd = float(np.std(v, ddof=1)) if v.size > 1 else float("nan")
    return Stat(float(np.mean(v)), sd, int(v.size))


def online_ranges_m(belief: Context, sim: SimResult, fractions, batch_s: float = 1.0,
                    memory_s: float = 600.0):
    """Online ORangE on a finished run: stream its recording through ``OnlineEstimator``
    (prior: ``belief``'s model and usable energy) and read the total range estimate (distance
    so far + remaining) at each fraction of the run's duration.

    Returns (list of range estimates [m], the estimator after the last fraction).
    """

    rec = recording_from_frame(sim.frame, f"{belief.scenario.name} run")
    state = recording_state(rec, belief.world, conditions=belief.conditions)
    est = OnlineEstimator(belief.model, belief.scenario.battery.usable_J, memory_s, memory_s)
    history = stream(est, state, rec.frame["power_W"].to_numpy(float), rec.t_s, batch_s,
                     until_s=max(fractions) * sim.duration_s)
    t = np.array([h.t_s for h in history])
    picks = [history[int(np.argmin(np.abs(t - f * sim.duration_s)))] for f in fractions]
    return [p.range_total_m for p in picks], est


def cells_by(rows: list[dict], levels: dict, measures: dict[str, str]) -> list[dict]:
    """One cell per combination of ``levels`` (row key -> its values, in table order): the
    level values and a ``Stat`` per measure (cell key -> row key) over the matching rows."""
    out = []
    for combo in itertools.product(*levels.values()):
        where = dict(zip(levels, combo))
        mine = [r for r in rows if all(r[k] == v for k, v in where.items())]
        out.append(where | {name: stat(r[key] for r in mine) for name, key in measures.items()})
    return out
