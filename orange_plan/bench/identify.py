"""Reproducible measurements: offline vs online range (simulated runs to depletion) and
calibration on held-out real recordings.

Offline vs online (the paper's AR Drone comparison, range accuracy
``1 - |d_pred - d_true| / d_true``; the route, the offline estimate and the accuracy are
``sim.ranges``'):

* online: the ``OnlineEstimator`` fed the recording's samples (1 s batches); the estimate
  at 20 % of the run (and the mean accuracy at 20, 40, 60, 80 %): distance so far +
  remaining energy / live energy per metre (memory and window 600 s). It sees the
  motion and the measured power, not the truth: wind columns are not recorded, so its
  features use the scenario's wind.
* truths (``BENCH_TRUTHS``): what the real world does differently from the scenario.
* reserve: the a-priori model's prediction of the whole run's energy along the recorded
  motion, with its predictive standard deviation; the run's recorded energy should exceed
  predicted + reserve(p) in at most a fraction 1 - p of runs (``RESERVE_CONFIDENCES``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from orange_plan.context import Context, load_context
from orange_plan.identify.calibrate import Calibrator
from orange_plan.identify.online import OnlineEstimator, stream
from orange_plan.physics.model_builder import model_with_terms
from orange_plan.planning.reserve import ConfidenceReserve
from orange_plan.sim.ranges import PREDICT_AT, accuracy_pct, lap_route, offline_range_m
from orange_plan.sim.simulator import simulate
from orange_plan.sim.truth import truth_from_dict
from orange_plan.telemetry.importers import FORMATS
from orange_plan.telemetry.recording import cumulative_J, recording_from_frame
from orange_plan.telemetry.replay import run_energy
from orange_plan.telemetry.state import recording_state

BENCH_TRUTHS: dict[str, dict] = {
    # the drone meets a stronger, gusty wind from another direction than forecast
    "ar_drone_wind": {
        "wind": {"mean_mps": 7.0, "from_deg": 220.0, "gust_std_mps": 3.0, "gust_tau_s": 5.0,
                 "recorded": False},
        "noise": {"power_std_W": 1.0}, "stops": {"every_s": 60.0},
    },
    # the lab floor rolls harder than assumed; electronics draw a little more
    "rusti_v1_box": {
        "coefficients": {"rolling_kg": 5.4, "ancillary_W": 6.3},
        "terrain": {"roughness_crr_std": 0.004, "roughness_length_m": 1.0},
        "noise": {"power_std_W": 0.3},
    },
    "rusti_v1_ramp": {
        "coefficients": {"rolling_kg": 5.4, "grade_kg": 4.2, "ancillary_W": 6.3},
        "terrain": {"roughness_crr_std": 0.004, "roughness_length_m": 1.0},
        "noise": {"power_std_W": 0.3},
    },
    # outdoors: wet grass rolls harder, skid-steer scrub is higher, a 0.8 kg payload at 10 min
    "rusti_v2_grass_1500mAh_v0544": {
        "coefficients": {"rolling_kg": 8.5, "turn_J_per_rad": 3.0},
        "payload": {"extra_kg": 0.8, "from_s": 600.0},
        "terrain": {"roughness_crr_std": 0.02, "roughness_length_m": 2.0},
        "noise": {"power_std_W": 0.5},
    },
}


@dataclass(frozen=True)
class OnlineRow:
    """One simulated run: true range and both estimates (accuracies in %).

    ``d_online_m`` / ``accuracy_online_pct`` are at ``PREDICT_AT[0]`` of the run;
    ``accuracy_online_mean_pct`` averages the online accuracy over all ``PREDICT_AT``.
    ``energy_predicted_prior_J`` / ``_sd_J``: the a-priori model's whole-run energy along the
    recorded motion and its predictive standard deviation (``_param_sd_J``: its coefficient
    covariance part alone, a reserve without the run-to-run discrepancy); ``energy_recorded_J`` the run's.
    """

    scenario: str
    seed: int
    d_true_m: float
    d_offline_m: float
    d_online_m: float
    d_online_sd_m: float
    accuracy_offline_pct: float
    accuracy_online_pct: float
    accuracy_online_mean_pct: float
    t_predict_s: float
    duration_s: float
    lap_m: float
    energy_recorded_J: float = float("nan")
    energy_predicted_prior_J: float = float("nan")
    energy_predicted_prior_sd_J: float = float("nan")
    energy_predicted_prior_param_sd_J: float = float("nan")

    def to_dict(self) -> dict:
        return asdict(self)


RESERVE_CONFIDENCES = (0.9, 0.95)
"""Confidences p at which the benchmarks check the reserve: a run's recorded energy should
exceed predicted + reserve(p) in at most a fraction 1 - p of runs."""


@dataclass(frozen=True)
class OnlineTrace:
    """Estimates of one simulated run over time (for figures), and the a-priori model's
    whole-run energy along the recorded motion (``telemetry.replay.RunEnergy``)."""

    scenario: str
    t_s: np.ndarray
    range_total_m: np.ndarray
    range_sd_m: np.ndarray
    d_true_m: float
    d_offline_m: float
    duration_s: float
    energy_recorded_J: float
    prior: object


def online_trace(ctx: Context, truth_dict: dict, seed: int, until_fraction: float = 1.0,
                 memory_s: float = 600.0, window_s: float = 600.0):
    """Simulate one run to depletion and stream it through the online estimator.

    Returns (OnlineTrace, list of OnlineEstimate, SimResult, route).
    """
    route = lap_route(ctx)
    sim = simulate(ctx, route, truth_from_dict(truth_dict, "bench truth"), seed=seed,
                   to_depletion=True)
    rec = recording_from_frame(sim.frame, f"{ctx.scenario.name} seed {seed}")
    state = recording_state(rec, ctx.world, conditions=ctx.conditions)
    est = OnlineEstimator(ctx.model, ctx.scenario.battery.usable_J, memory_s, window_s)
    history = stream(est, state, rec.frame["power_W"].to_numpy(float), rec.t_s,
                     until_s=until_fraction * sim.duration_s)
    trace = OnlineTrace(ctx.scenario.name, np.array([h.t_s for h in history]),
                        np.array([h.range_total_m for h in history]),
                        np.array([h.range_remaining_sd_m for h in history]), sim.distance_m,
                        offline_range_m(ctx, route), sim.duration_s, rec.energy_J,
                        run_energy(rec, ctx.model, state))
    return trace, history, sim, route


def online_run(ctx: Context, truth_dict: dict, seed: int, predict_at=PREDICT_AT,
               memory_s: float = 600.0, window_s: float = 600.0) -> OnlineRow:
    """Simulate one run to depletion and compare offline and online range estimates."""
    trace, history, sim, route = online_trace(ctx, truth_dict, seed, max(predict_at),
                                              memory_s, window_s)
    picks = [history[int(np.argmin(np.abs(trace.t_s - f * sim.duration_s)))] for f in predict_at]
    acc = [accuracy_pct(p.range_total_m, sim.distance_m) for p in picks]
    return OnlineRow(ctx.scenario.name, seed, sim.distance_m, trace.d_offline_m,
                     picks[0].range_total_m, picks[0].range_remaining_sd_m,
                     accuracy_pct(trace.d_offline_m, sim.distance_m), acc[0],
                     float(np.mean(acc)), picks[0].t_s, sim.duration_s, route.length_m,
                     trace.energy_recorded_J, trace.prior.energy_J, trace.prior.sd_J,
                     trace.prior.param_sd_J)


def online_benchmark(scenario_dir: str | Path, scenarios=None, seeds=(0, 1, 2),
                     progress=None) -> list[OnlineRow]:
    """Offline vs online range accuracy on simulated runs to depletion (module docstring)."""
    names = list(BENCH_TRUTHS) if scenarios is None else list(scenarios)
    rows = []
    for name in names:
        ctx = load_context(Path(scenario_dir) / f"{name}.toml")
        truth = BENCH_TRUTHS.get(name, {})
        for seed in seeds:
            rows.append(online_run(ctx, truth, seed))
            if progress:
                progress()
    return rows


def summarise(rows, key: str = "scenario") -> list[dict]:
    """Mean accuracy per scenario (offline, online) over seeds; runs exceeding the a-priori
    prediction + reserve(p) (``coverage_summary``, suffix ``_prior``; ``_prior_param`` with the
    reserve from the coefficient covariance alone)."""
    out = []
    for name in dict.fromkeys(getattr(r, key) for r in rows):
        mine = [r for r in rows if getattr(r, key) == name]
        out.append({
            key: name, "runs": len(mine),
            "d_true_m": float(np.mean([r.d_true_m for r in mine])),
            "accuracy_offline_pct": float(np.mean([r.accuracy_offline_pct for r in mine])),
            "accuracy_online_pct": float(np.mean([r.accuracy_online_pct for r in mine])),
            "accuracy_online_mean_pct": float(np.mean([r.accuracy_online_mean_pct
                                                       for r in mine])),
            "sd_rel_prior_mean": float(np.mean([r.energy_predicted_prior_sd_J
                                                / r.energy_predicted_prior_J for r in mine])),
            "energy_error_prior_pct": float(np.mean([
                100 * (r.energy_predicted_prior_J / r.energy_recorded_J - 1) for r in mine])),
            **coverage_summary([r.energy_recorded_J for r in mine],
                               [r.energy_predicted_prior_J for r in mine],
                               [r.energy_predicted_prior_sd_J for r in mine], "_prior"),
            **coverage_summary([r.energy_recorded_J for r in mine],
                               [r.energy_predicted_prior_J for r in mine],
                               [r.energy_predicted_prior_param_sd_J for r in mine],
                               "_prior_param"),
        })
    return out


# --- calibration on real recordings ---------------------------------------------------------

CALIBRATION_CASES = {
    # dataset: (scenario, importer format, file glob, Calibrator settings)
    "husky_borealtc": ("husky_a200", "borealtc", "borealtc/*/pro_*.csv",
                       {"terms": ["ancillary", "rolling_torque", "turning_torque"],
                        "yaw_rate_column": "wheel_yaw_rate_radps"}),
    "bmw_i3_tum": ("bmw_i3", "tum_bmw_i3", "tum_bmw_i3/Trip*.csv.gz",
                   {"fixed": ["hvac_fraction"]}),
}
"""Real-data calibration cases. Husky: BorealTC's power is 24 V x motor current, i.e. wheel
torque, so the model is the idle draw plus Coulomb rolling and skid-steer scrub torques
(``rolling_torque``, ``turning_torque``), the scrub fed by the wheels' yaw rate (it follows
the wheels, BorealTC importer notes); chosen by 2-fold cross-validation inside each fitting
half (docs/benchmarks/calibration.md). BMW: the scenario's model (rolling, drag, grade, inertia, regen, the measured
cabin HVAC power and the cold-start ``drift``), the HVAC share held at its physical value 1
(the compressor is on the traction battery's bus; standstill power confirms ~1.1): amid
kilowatts of traction noise the fit cannot pin it (0.1-0.8 between halves)."""


@dataclass(frozen=True)
class CalibrationRow:
    """One held-out run: recorded vs predicted whole-run energy, calibrated and a priori
    (offline), with each prediction's predictive standard deviation (``_sd_J``: coefficient
    covariance plus run-to-run discrepancy, what a confidence reserve is sized from; the
    calibrated model's ``discrepancy_rel_sd`` is estimated on its training runs only;
    ``_param_sd_J`` the coefficient covariance part alone, a reserve without the run-to-run discrepancy), and
    online (``online_energy_errors``): ``online_error_pct`` at ``PREDICT_AT[0]`` of the run
    starting from the calibrated model, ``online_error_mean_abs_pct`` the mean |error| over
    ``PREDICT_AT``, and ``online_prior_error_pct`` at ``PREDICT_AT[0]`` starting from the
    a-priori model."""

    dataset: str
    fold: int
    run: str
    energy_recorded_J: float
    energy_predicted_J: float
    energy_error_pct: float
    energy_error_prior_pct: float
    online_error_pct: float
    online_error_mean_abs_pct: float
    online_prior_error_pct: float
    energy_predicted_sd_J: float = float("nan")
    energy_predicted_prior_J: float = float("nan")
    energy_predicted_prior_sd_J: float = float("nan")
    discrepancy_rel_sd: float = float("nan")
    energy_predicted_param_sd_J: float = float("nan")
    energy_predicted_prior_param_sd_J: float = float("nan")

    def to_dict(self) -> dict:
        return asdict(self)


def count_runs(data_dir: str | Path, datasets) -> int:
    """Runs ``calibration_benchmark`` will hold out (each once): its progress total."""
    return sum(len(list(Path(data_dir).glob(CALIBRATION_CASES[name][2]))) for name in datasets)


def load_runs(data_dir: str | Path, fmt: str, pattern: str) -> list:
    """Import and check every run matching ``pattern`` under ``data_dir`` (sorted by path)."""
    paths = sorted(Path(data_dir).glob(pattern))
    return [recording_from_frame(FORMATS[fmt](p), f"{p.parent.name}/{p.name}") for p in paths]


def whole_run_prediction(model, rec, ctx, settings: dict):
    """Predicted battery energy of a recording's motion under ``model`` (gaps skipped) and its
    predictive standard deviation (``telemetry.replay.RunEnergy``)."""

    state = recording_state(rec, ctx.world, conditions=ctx.conditions,
                            grade_window_m=settings.get("grade_window_m"),
                            yaw_rate_column=settings.get("yaw_rate_column"))
    return run_energy(rec, model, state)


def whole_run_energy_J(model, rec, ctx, settings: dict) -> float:
    """Predicted battery energy of a recording's motion under ``model`` (gaps skipped) [J]."""
    return whole_run_prediction(model, rec, ctx, settings).energy_J


def reserve_exceeded(recorded_J, predicted_J, sd_J, confidence: float) -> np.ndarray:
    """True where a recorded energy exceeds predicted + the ``confidence`` reserve, the
    reserve sized exactly as the planner sizes it (``planning.reserve``)."""

    sd = np.asarray(sd_J, float)
    reserve = ConfidenceReserve(confidence).size_J(0.0, sd**2, 0.0)
    return np.asarray(recorded_J, float) > np.asarray(predicted_J, float) + reserve


def coverage_summary(recorded_J, predicted_J, sd_J, suffix: str = "") -> dict:
    """Runs exceeding predicted + reserve(p), per ``RESERVE_CONFIDENCES``: percentage and
    count (``exceed_p90_pct``, ``exceed_p90_runs``...; honest when the percentage is at most
    100 (1 - p))."""
    out = {}
    for p in RESERVE_CONFIDENCES:
        hit = reserve_exceeded(recorded_J, predicted_J, sd_J, p)
        tag = f"p{round(100 * p)}"
        out[f"exceed_{tag}{suffix}_pct"] = 100.0 * float(np.mean(hit))
        out[f"exceed_{tag}{suffix}_runs"] = int(np.sum(hit))
    return out


def online_energy_errors(model, rec, ctx, settings: dict, fractions=PREDICT_AT,
                         memory_s: float = 600.0) -> list[float]:
    """Online whole-run energy prediction on a recording, signed error [%] per fraction.

    The first part of the run streams through ``OnlineEstimator`` (prior = ``model``); at each
    fraction f of the run's duration the whole-run energy is predicted as the energy measured
    so far plus the current coefficients' prediction for the rest of the motion (the route
    ahead is known, as in a planned mission). Errors are (predicted - recorded) / recorded.
    """
    state = recording_state(rec, ctx.world, conditions=ctx.conditions,
                            grade_window_m=settings.get("grade_window_m"),
                            yaw_rate_column=settings.get("yaw_rate_column"))
    t, power = rec.t_s, rec.frame["power_W"].to_numpy(float)
    duration = float(t[-1] - t[0])
    est = OnlineEstimator(model, ctx.scenario.battery.usable_J, memory_s, memory_s)
    history = stream(est, state, power, t, until_s=max(fractions) * duration)
    measured = cumulative_J(rec, power)
    errors = []
    for f in fractions:
        pick = min(history, key=lambda h: abs(h.t_s - f * duration))
        k = min(int(np.searchsorted(t, t[0] + pick.t_s - 1e-9)), t.size - 1)  # samples seen
        now = model.with_theta(pick.theta)
        ahead = cumulative_J(rec, np.asarray(now.power_W(state), float) * np.ones(t.size))
        predicted = measured[k] + ahead[-1] - ahead[k]
        errors.append(100 * (predicted - measured[-1]) / measured[-1])
    return errors


def calibration_benchmark(data_dir: str | Path, scenario_dir: str | Path, datasets=None,
                          progress=None) -> list[CalibrationRow]:
    """Two-fold run-level hold-out: fit on every other run (sorted by name), predict the
    whole-run energy of the others, then swap. Errors are (predicted - recorded) / recorded."""

    rows = []
    for name in datasets or CALIBRATION_CASES:
        scenario, fmt, pattern, settings = CALIBRATION_CASES[name]
        ctx = load_context(Path(scenario_dir) / f"{scenario}.toml")
        runs = load_runs(data_dir, fmt, pattern)
        prior = model_with_terms(ctx, settings.get("terms"))
        for fold in (0, 1):
            train, test = runs[fold::2], runs[1 - fold::2]
            cal = Calibrator(**settings).fit(train, ctx)
            for rec in test:
                recorded = rec.energy_J
                fitted = whole_run_prediction(cal.model_, rec, ctx, settings)
                before = whole_run_prediction(prior, rec, ctx, settings)
                pred, pred0 = fitted.energy_J, before.energy_J
                online = online_energy_errors(cal.model_, rec, ctx, settings)
                online0 = online_energy_errors(prior, rec, ctx, settings, PREDICT_AT[:1])
                rows.append(CalibrationRow(name, fold, rec.source, recorded, pred,
                                           100 * (pred - recorded) / recorded,
                                           100 * (pred0 - recorded) / recorded, online[0],
                                           float(np.mean(np.abs(online))), online0[0],
                                           fitted.sd_J, pred0, before.sd_J,
                                           cal.discrepancy_rel_sd_, fitted.param_sd_J,
                                           before.param_sd_J))
                if progress:
                    progress()
    return rows


def summarise_calibration(rows) -> list[dict]:
    """Per dataset: held-out runs, mean and max |error|, pooled error (sum of energies), and
    how often the recorded energy exceeded predicted + reserve(p) (``coverage_summary``;
    suffix ``_prior`` for the a-priori model; ``_param`` / ``_prior_param`` with the reserve
    from the coefficient covariance alone), with the discrepancies used."""
    out = []
    for name in dict.fromkeys(r.dataset for r in rows):
        mine = [r for r in rows if r.dataset == name]
        rec = sum(r.energy_recorded_J for r in mine)
        pred = sum(r.energy_predicted_J for r in mine)
        err = np.abs([r.energy_error_pct for r in mine])
        out.append({
            "dataset": name, "held_out_runs": len(mine),
            "mean_abs_error_pct": float(np.mean(err)),
            "median_abs_error_pct": float(np.median(err)),
            "max_abs_error_pct": float(np.max(err)),
            "pooled_error_pct": 100 * (pred - rec) / rec,
            "mean_abs_error_prior_pct": float(np.mean(np.abs([r.energy_error_prior_pct
                                                              for r in mine]))),
            "online_mean_abs_error_pct": float(np.mean(np.abs([r.online_error_pct
                                                               for r in mine]))),
            "online_max_abs_error_pct": float(np.max(np.abs([r.online_error_pct
                                                             for r in mine]))),
            "online_mean_abs_error_over_run_pct": float(np.mean([r.online_error_mean_abs_pct
                                                                 for r in mine])),
            "online_prior_mean_abs_error_pct": float(np.mean(np.abs(
                [r.online_prior_error_pct for r in mine]))),
            "discrepancy_rel_sd": float(np.mean([r.discrepancy_rel_sd for r in mine])),
            "sd_rel_mean": float(np.mean([r.energy_predicted_sd_J / r.energy_predicted_J
                                          for r in mine])),
            "sd_rel_prior_mean": float(np.mean([r.energy_predicted_prior_sd_J
                                                / r.energy_predicted_prior_J for r in mine])),
            **coverage_summary([r.energy_recorded_J for r in mine],
                               [r.energy_predicted_J for r in mine],
                               [r.energy_predicted_sd_J for r in mine]),
            **coverage_summary([r.energy_recorded_J for r in mine],
                               [r.energy_predicted_prior_J for r in mine],
                               [r.energy_predicted_prior_sd_J for r in mine], "_prior"),
            **coverage_summary([r.energy_recorded_J for r in mine],
                               [r.energy_predicted_J for r in mine],
                               [r.energy_predicted_param_sd_J for r in mine], "_param"),
            **coverage_summary([r.energy_recorded_J for r in mine],
                               [r.energy_predicted_prior_J for r in mine],
                               [r.energy_predicted_prior_param_sd_J for r in mine],
                               "_prior_param"),
        })
    return out
