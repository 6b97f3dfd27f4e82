"""``bench diagnose --real DIR``: regeneration on the real BMW i3 trips.

Each trip of ``DIR/tum_bmw_i3`` is diagnosed with the ``bmw_i3`` scenario *without* its
``inertia`` and ``regen`` terms, so that both are left for diagnosis to find. Reported per
trip: whether ``regen`` was named, its fitted efficiency (the share of the negative traction
power ``F v`` returned to the battery) and standard error, and the held-out RMSE of
inertia alone and of inertia with regeneration, both inside the model (a braking sample
returns nothing with inertia alone, ``eff`` of its negative traction power with regen), with
the relative gain of the second over the first, and what the trip can tell of the
efficiency: its profile likelihood over ``EFFICIENCY_GRID`` (every other coefficient refitted
at each efficiency, inside the model) read as a 95 % interval, the efficiencies whose
deviance ``n_eff ln(RSS(eff) / RSS_min)`` (``n_eff`` the samples over the residual's
autocorrelation time) is under ``CHI2_95``. An interval that reaches 1 says the trip cannot
tell a plausible efficiency from a lossless one.

And what the car itself says, where the trip has the drive's torque signal
(``motor_torque_Nm``): ``torque_efficiency``, the motor's power on the braking samples
(torque times the motor's speed, ``v * I3_GEAR_RATIO / I3_WHEEL_RADIUS_M``) over the negative
traction power of the fitted model (inertia and regeneration inside it) on the same samples.
It is an estimate of the same efficiency that does not come from regressing the battery's
power, so it tells a fitted efficiency near 1 that the car delivered from one the fit made up.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from orange_plan.errors import InputError

REMOVED = ("inertia", "regen")
"""Terms taken out of the scenario before diagnosis."""
TRIPS = "tum_bmw_i3/Trip*.csv.gz"
"""The trips, under the data folder."""
EFFICIENCY_GRID = np.round(np.arange(0.05, 1.0001, 0.025), 3)
"""Efficiencies the profile likelihood is evaluated at [-]."""
CHI2_95 = 3.84
"""95 % quantile of chi-square with one degree of freedom: the deviance bound of the
efficiency's interval [-]."""
I3_GEAR_RATIO = 9.665
"""BMW i3 single-speed reduction, motor to wheel (technical data) [-]."""
I3_WHEEL_RADIUS_M = 0.35
"""BMW i3 155/70 R19 tyre: 241 mm rim radius + 0.7 x 155 mm sidewall [m]."""
PROFILE_ROUNDS = 3
"""Gauss-Newton rounds of each fixed-efficiency refit (the clip moves with the force) [-]."""


@dataclass(frozen=True)
class RegenRow:
    """One trip: what diagnosis named and the regeneration it fitted (module docstring)."""

    trip: str
    samples: int
    found: list
    regen_named: bool
    regen_efficiency: float
    regen_efficiency_sd: float
    inertia_holdout_rmse_W: float
    inertia_regen_holdout_rmse_W: float
    regen_gain_pct: float
    regen_t: float
    efficiency_low: float
    efficiency_high: float
    braking_share: float
    torque_efficiency: float
    seconds: float

    def to_dict(self) -> dict:
        return asdict(self)


def bmw_regen(data_dir: str | Path, scenario_path: str | Path,
              pattern: str = TRIPS) -> list[RegenRow]:
    """Diagnose every BMW i3 trip under ``data_dir`` matching ``pattern`` (module docstring).

    Raises
    ------
    InputError
        No trip under ``data_dir``.
    """
    from orange_plan.bench.identify import load_runs
    from orange_plan.context import load_context
    from orange_plan.identify.diagnose import candidates, diagnose, fit_design, polish
    from orange_plan.physics.model_builder import model_with_terms

    runs = load_runs(data_dir, "tum_bmw_i3", pattern)
    if not runs:
        raise InputError(f"no BMW i3 trip ({pattern}) under {data_dir}")
    ctx = load_context(scenario_path)
    ctx = replace(ctx, model=model_with_terms(
        ctx, [t for t in ctx.model.term_ids if t not in REMOVED]))
    pool = {c.id: c for c in candidates()}
    rows = []
    for rec in runs:
        start = time.perf_counter()
        result = diagnose(rec, ctx)
        seconds = time.perf_counter() - start
        d = result.design
        inertia = [pool["inertia"]]
        alone = polish(d, inertia, fit_design(d, inertia))
        both = fit_design(d, [*inertia, pool["regen"]])
        eff = dict(zip(both.names, both.theta))["regen.regen_efficiency"]
        sd = dict(zip(both.names, both.sd))["regen.regen_efficiency"]
        low, high = efficiency_interval(d, inertia, pool["regen"], both)
        found = [f.term for f in result.findings]
        rows.append(RegenRow(
            trip=str(rec.source), samples=d.n, found=found, regen_named="regen" in found,
            regen_efficiency=float(eff), regen_efficiency_sd=float(sd),
            inertia_holdout_rmse_W=alone.cv_rmse_W, inertia_regen_holdout_rmse_W=both.cv_rmse_W,
            regen_gain_pct=100.0 * (1.0 - both.cv_rmse_W / alone.cv_rmse_W),
            regen_t=max((t.t_max for t in result.trials if t.id == "regen"), default=0.0),
            efficiency_low=low, efficiency_high=high,
            braking_share=float(np.mean(d.y < 0)),
            torque_efficiency=torque_efficiency(d, [*inertia, pool["regen"]], both),
            seconds=seconds))
    return rows


def torque_efficiency(d, chosen: list, fit) -> float:
    """The motor's power over the fitted model's negative traction power, summed over the
    samples where that power is negative (module docstring); NaN without a torque signal [-]."""
    from orange_plan.identify.diagnosis.fitting import absorb

    if "motor_torque_Nm" not in d.columns_of:
        return float("nan")
    inside = absorb(d, chosen, fit).design
    speed = np.asarray(inside.state.speed_mps, float)
    traction_W = np.asarray(inside.base.traction_force_N(inside.state), float) * speed
    motor_W = d.frame["motor_torque_Nm"].to_numpy(float) * speed * I3_GEAR_RATIO \
        / I3_WHEEL_RADIUS_M
    braking = traction_W < 0
    return float(np.sum(motor_W[braking]) / np.sum(traction_W[braking]))


def efficiency_interval(d, chosen: list, regen, fit) -> tuple[float, float]:
    """The 95 % profile-likelihood interval of the efficiency on ``EFFICIENCY_GRID``
    (``identify.diagnosis.fitting.efficiency_profile``): its lowest and highest efficiency
    under ``CHI2_95``."""
    from orange_plan.identify.diagnosis.fitting import efficiency_profile

    deviance = efficiency_profile(d, chosen, regen, fit, EFFICIENCY_GRID, PROFILE_ROUNDS)
    inside = EFFICIENCY_GRID[deviance <= CHI2_95]
    return float(inside.min()), float(inside.max())
