"""``orange-plan bench flights``: the aerial model against real DJI Matrice 100 survey flights.

Data: the WADL flights (``wadl_m100``: 68 autonomous penguin-colony surveys, battery voltage
and current, the uploaded waypoint mission and the waypoint-reached times; GPL-3.0, read where
they are, never shipped). Each flight's whole energy (take-off to touch-down) is predicted
four ways, all with leave-one-route-out cross-validation (a route flown several times is
never both fitted and predicted; the fit sees only the other routes' flights):

* ``recording``: the fold's calibrated model replayed along the flight's recorded motion
  (``orange-plan predict``);
* ``route``: the fold's calibrated model on the planned route alone, flown by
  ``planning.mission_check`` (take-off climb, legs at their planned speeds, corners on their
  radii or stops at every waypoint, the landing) (``orange-plan check``);
* ``per_metre``: the training flights' energy per metre times the route's planned length;
* ``power_time``: the training flights' mean power times the route's planned time (each
  leg's length over its planned speed, the take-off climb and landing at the scenario's
  vertical speeds): what an operator's flight-time estimate gives.

Flights whose survey legs were flown at transit speed (``speed_anomaly``: about 0.43 x the
planned leg time) cannot be predicted from their plan: they are listed apart and left out of
the medians and of the reserve check, never dropped silently.

Reserve: the route prediction's sd is the fold model's coefficient part plus a route-level
run-to-run discrepancy measured on the fold's training flights (``route_discrepancy``: a part
relative to the flight's energy and a fixed part); ``reserve(p)`` is the planner's confidence
reserve ``z_p sd``. The share of held-out flights whose recorded energy
exceeds ``route + reserve(p)`` is reported per fold and pooled.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from orange_plan.errors import InputError
from orange_plan.export.missions_in import Mission, MissionWaypoint
from orange_plan.identify.calibrate import Calibrator, recording_samples
from orange_plan.physics.model_builder import model_with_terms
from orange_plan.planning.mission_check import mission_samples
from orange_plan.planning.reserve import ConfidenceReserve
from orange_plan.telemetry.importers.wadl import read_wadl, read_wadl_meta, read_wadl_route
from orange_plan.telemetry.recording import recording_from_frame
from orange_plan.telemetry.replay import run_energy
from orange_plan.telemetry.state import recording_state

DATASET = "wadl_m100"
TERMS = ("ancillary", "hover", "aero_drag", "grade", "regen")
"""Terms fitted per fold: the scenario's reference aerial terms and the descent recovery."""
RESERVE_CONFIDENCES = (0.9, 0.95)
FIT_EVERY = 3
"""Samples of the 1 s recording grid kept for the per-fold fits (one in this many)."""
METHODS = ("recording", "route", "per_metre", "power_time")


@dataclass(frozen=True)
class Flight:
    """One WADL flight: its recording, its planned mission and what its metadata says."""

    id: str
    route: str
    fly_mode: str
    speed_anomaly: bool
    energy_J: float
    duration_s: float
    planned_length_m: float
    recording: object = field(repr=False)
    mission: Mission = field(repr=False)


def wadl_mission(path: Path, meta: dict) -> Mission:
    """The uploaded waypoint mission of a flight: home at the take-off point, the route's
    waypoints (speed of the leg leaving each, hold, corner radius on CURVED routes; NORMAL
    routes stop at every waypoint), landing at the last waypoint (``AUTO_LAND``)."""
    route = read_wadl_route(path)
    curved = meta.get("route_fly_mode") == "CURVED"

    def number(value):
        return None if value is None or pd.isna(value) else float(value)

    home = MissionWaypoint(0.0, 0.0, 0.0, speed_mps=number(meta.get("route_initial_speed_mps")))
    wps = [home] + [MissionWaypoint(float(w.x_m), float(w.y_m), float(w.z_m),
                                    speed_mps=number(w.speed_to_next_mps),
                                    stay_s=number(w.stay_s) or 0.0,
                                    corner_radius_m=number(w.corner_radius_m) if curved
                                    else None)
                    for w in route.itertuples()]
    # the colonies lie 120-190 m below the take-off ridge and the map has no elevation: the
    # check runs in the flight's own frame (``in_map_frame=False``), the terrain unknown
    return Mission(tuple(wps), takeoff_alt_m=None, returns_home=False, source=Path(path).name)


def flight_paths(folder: Path, limit: int | None = None) -> list[Path]:
    """The flights' battery tables in ``folder`` (sorted by name, at most ``limit``)."""
    paths = sorted(p.with_suffix(".csv") for p in Path(folder).glob("*.json")
                   if p.with_suffix(".csv").is_file())
    if not paths:
        raise InputError(f"{folder}: no WADL flight (<id>.json with <id>.csv) found")
    return paths[:limit] if limit else paths


def load_flight(path: Path) -> Flight:
    meta = read_wadl_meta(path)
    rec = recording_from_frame(read_wadl(path), source=str(path))
    return Flight(meta.get("flight_id", path.stem), str(meta.get("route_name")),
                  str(meta.get("route_fly_mode")), bool(meta.get("speed_anomaly")),
                  float(meta["energy_J"]), float(meta["duration_s"]),
                  float(meta["route_planned_length_incl_landing_m"]), rec,
                  wadl_mission(path, meta))


def planned_time_s(mission: Mission, climb_mps: float, descent_mps: float) -> float:
    """The operator's flight-time estimate: each leg's 3-D length over its planned speed, the
    first climb and the landing at the vertical speeds [s]."""
    wps = mission.waypoints
    total = 0.0
    for a, b in itertools.pairwise(wps):
        length = math.dist((a.x_m, a.y_m, a.z_m), (b.x_m, b.y_m, b.z_m))
        total += length / (a.speed_mps or climb_mps)
    return total + wps[-1].z_m / descent_mps


@dataclass
class _Prepared:
    """What every fold reuses: recording samples, route samples, per-flight constants."""

    flights: list
    samples: object
    route_states: list
    route_weights: list
    planned_time_s: np.ndarray


def prepare(flights: list[Flight], ctx) -> _Prepared:
    samples = recording_samples([f.recording for f in flights], ctx)
    # the battery is read about every 10 s: every FIT_EVERY-th second of the 1 s grid carries
    # the same information for the fit, at a third of its cost
    keep = np.zeros(samples.power_W.size, bool)
    keep[::FIT_EVERY] = True
    samples = samples.subset(keep)
    states, weights = [], []
    for f in flights:
        state, weight = mission_samples(f.mission, ctx, in_map_frame=False)
        states.append(state)
        weights.append(weight)
    robot = ctx.scenario.robot
    climb = robot.climb_mps or 2.5
    descent = robot.descent_mps or 1.5
    times = np.array([planned_time_s(f.mission, climb, descent) for f in flights])
    return _Prepared(flights, samples, states, weights, times)


def _route_energy(model, state, weight) -> tuple[float, np.ndarray]:
    """Energy of route samples under ``model`` and its gradient in the coefficients."""
    n = weight.size
    power = np.broadcast_to(np.asarray(model.power_W(state), float), (n,))
    jac = np.broadcast_to(np.asarray(model.power_jacobian(state), float), (n, len(model.names)))
    return float(power @ weight), jac.T @ weight


def route_discrepancy(recorded, predicted, param_var) -> tuple[float, float]:
    """Run-to-run discrepancy of route predictions: ``(rel_sd, fixed_sd_J)`` with

        E[2 max(e, 0)^2] - g'Cov g = rel_sd^2 E^2 + fixed_sd_J^2,   e = recorded - predicted

    fitted by non-negative least squares over the flights: the upper semi-variance of the
    errors (``identify.calibrate``'s rule for recordings: a reserve guards against flights
    drawing more) split into a part growing with the flight (wind, speed held) and a fixed
    part (how long the take-off, the hover before the landing and the landing itself take,
    which the operator, not the route, sets: +-10 s whatever the route's length).
    """
    from scipy.optimize import nnls

    err = recorded - predicted
    target = 2.0 * np.maximum(err, 0.0) ** 2 - param_var
    scale = float(np.mean(predicted**2))
    design = np.column_stack([predicted**2 / scale, np.ones_like(predicted)])
    (a, b), _ = nnls(design, target / scale)
    return float(math.sqrt(a)), float(math.sqrt(b * scale))


def run_fold(prep: _Prepared, ctx, test: np.ndarray, terms=TERMS) -> list[dict]:
    """Fit on the flights not in ``test`` (a boolean mask), predict those in it."""
    flights = prep.flights
    train = ~test
    blocks = prep.samples.block[:, 0]
    cal = Calibrator(terms=list(terms), holdout_every=0, discrepancy_folds=2).fit_samples(
        prep.samples.subset(np.isin(blocks, np.flatnonzero(train))),
        model_with_terms(ctx, list(terms)), ctx.scenario)
    model = cal.model_
    recorded = np.array([f.energy_J for f in flights])
    length = np.array([f.planned_length_m for f in flights])
    nominal = np.array([not f.speed_anomaly for f in flights])
    fit_on = train & nominal
    per_metre = recorded[fit_on].sum() / length[fit_on].sum()
    mean_power = recorded[fit_on].sum() / np.array([f.duration_s for f in flights])[fit_on].sum()
    route = [_route_energy(model, s, w) for s, w in zip(prep.route_states, prep.route_weights)]
    route_e = np.array([e for e, _ in route])
    param_var = np.array([g @ model.cov @ g for _, g in route])
    rel_sd, fixed_sd = route_discrepancy(recorded[fit_on], route_e[fit_on], param_var[fit_on])
    rows = []
    for i in np.flatnonzero(test):
        f = flights[i]
        state = recording_state(f.recording, ctx.world, conditions=ctx.conditions)
        replay = run_energy(f.recording, model, state)
        sd = math.sqrt(param_var[i] + (rel_sd * route_e[i]) ** 2 + fixed_sd**2)
        row = {"flight": f.id, "route": f.route, "fly_mode": f.fly_mode,
               "speed_anomaly": f.speed_anomaly, "recorded_J": f.energy_J,
               "duration_s": f.duration_s,
               "recording_J": replay.energy_J * f.energy_J / f.recording.energy_J,
               "route_J": float(route_e[i]), "route_sd_J": sd,
               "route_duration_s": float(prep.route_weights[i].sum()),
               "per_metre_J": per_metre * length[i],
               "power_time_J": mean_power * prep.planned_time_s[i],
               "route_discrepancy_rel_sd": rel_sd, "route_discrepancy_fixed_J": fixed_sd,
               "hover_W": model.coefficient("hover_W")}
        for p in RESERVE_CONFIDENCES:
            reserve = float(ConfidenceReserve(p).size_J(0.0, sd**2, 0.0))
            row[f"exceeds_{p:g}"] = bool(f.energy_J > route_e[i] + reserve)
        for method in METHODS:
            row[f"{method}_err_pct"] = 100.0 * (row[f"{method}_J"] - f.energy_J) / f.energy_J
        rows.append(row)
    return rows


def a_priori(ctx):
    """The scenario without its calibrated coefficients (its [model] table keeps only the
    term list): what the folds start from, so no fold sees a value fitted on its flights."""
    from dataclasses import replace

    from orange_plan.context import context_of
    from orange_plan.scenario import ModelSpec

    spec = ModelSpec(terms=ctx.scenario.model.terms)
    return context_of(replace(ctx.scenario, model=spec))


def check_benchmark(flights: list[Flight], ctx, terms=TERMS, progress=None) -> list[dict]:
    """Leave-one-route-out over the flights: one row per flight (``run_fold``), every fold
    fitted from the scenario's a priori values (``a_priori``)."""
    ctx = a_priori(ctx)
    prep = prepare(flights, ctx)
    routes = np.array([f.route for f in flights])
    rows = []
    for name in dict.fromkeys(routes):
        rows += [dict(r, fold=name) for r in run_fold(prep, ctx, routes == name, terms)]
        if progress:
            progress()
    return rows


def summarise(rows: list[dict]) -> dict:
    """Medians of |error| per method over the nominal flights, the anomalies apart, the
    reserve coverage pooled and per fold, and the targets."""
    frame = pd.DataFrame(rows)
    nominal = frame[~frame["speed_anomaly"]]
    median = {m: float(nominal[f"{m}_err_pct"].abs().median()) for m in METHODS}
    coverage = {}
    for p in RESERVE_CONFIDENCES:
        col = f"exceeds_{p:g}"
        per_fold = nominal.groupby("fold")[col].agg(["sum", "count"])
        coverage[f"{p:g}"] = {
            "allowed_pct": 100.0 * (1 - p),
            "exceeded": int(nominal[col].sum()), "flights": len(nominal),
            "exceeded_pct": 100.0 * float(nominal[col].mean()),
            "folds": len(per_fold), "folds_with_exceedance": int((per_fold["sum"] > 0).sum()),
            "worst_fold_pct": 100.0 * float((per_fold["sum"] / per_fold["count"]).max())}
    by_mode = {mode: {m: float(g[f"{m}_err_pct"].abs().median()) for m in METHODS}
               for mode, g in nominal.groupby("fly_mode")}
    anomalies = frame[frame["speed_anomaly"]][["flight", "route", "recorded_J"] + [
        f"{m}_err_pct" for m in METHODS]].to_dict("records")
    return {
        "flights": len(frame), "nominal": len(nominal), "folds": int(frame["fold"].nunique()),
        "median_abs_err_pct": median, "median_abs_err_pct_by_fly_mode": by_mode,
        "median_err_pct": {m: float(nominal[f"{m}_err_pct"].median()) for m in METHODS},
        "route_duration_err_pct_median": float(
            (100 * (nominal["route_duration_s"] / nominal["duration_s"] - 1)).median()),
        "targets": {
            "route_le_5pct": median["route"] <= 5.0,
            "route_1.5x_better_than_power_time": median["power_time"] >= 1.5 * median["route"],
            "recording_le_3pct": median["recording"] <= 3.0},
        "reserve": coverage, "speed_anomalies": anomalies}


def write_json(path: Path, payload: dict) -> None:
    path.write_text(json.dumps(payload, indent=1, default=float), encoding="utf-8")


def diagnose_flights(flights: list[Flight], ctx, n: int) -> dict:
    """``identify.diagnose`` with the a priori scenario on the first ``n`` nominal flights:
    how often each missing term was found, and each flight's verdict and evidence (with the
    detection limits it states when nothing is found)."""
    from collections import Counter

    from orange_plan.identify.diagnose import diagnose

    ctx = a_priori(ctx)
    found, per_flight = Counter(), []
    for f in [f for f in flights if not f.speed_anomaly][:n]:
        result = diagnose(f.recording, ctx)
        terms = [x.term for x in result.findings]
        found.update(terms)
        limits = {}
        for trial in result.trials:  # single candidates, first round: the limit they state
            if "+" not in trial.id and np.isfinite(trial.detectable_W):
                limits.setdefault(trial.id, float(trial.detectable_W))
        mean_W = f.energy_J / f.duration_s
        per_flight.append({"flight": f.id, "found": terms, "verdict": result.verdict,
                           "evidence": result.evidence, "mean_power_W": mean_W,
                           "detection_limit_W": limits,
                           "energy_error_pct_before": result.energy_error_pct(result.baseline),
                           "energy_error_pct_after": result.energy_error_pct(result.improved)})
    return {"flights": len(per_flight), "found": dict(found.most_common()),
            "detection_limit_pct_median": _median_limits(per_flight),
            "per_flight": per_flight}


def _median_limits(per_flight: list[dict]) -> dict:
    """Per candidate: the median over flights of its detection limit, % of the mean power,
    and on how many flights it was tried."""
    pct: dict[str, list] = {}
    for row in per_flight:
        for cand, watts in row["detection_limit_W"].items():
            pct.setdefault(cand, []).append(100.0 * watts / row["mean_power_W"])
    return {cand: {"median_pct": float(np.median(v)), "flights": len(v)}
            for cand, v in sorted(pct.items())}
