"""Truths that differ from the planning model within its calibration uncertainty.

A benchmark of plans with a guaranteed return must fly them in a world the planner does not
know exactly, but one it *could* be: each truth draws the model's lumped coefficients from
their covariance (``EnergyModel.theta``, ``EnergyModel.cov``: the calibration's, or the
a-priori ``prior_relative_stderr`` one), scales them all by one run factor drawn from the
model's run-to-run discrepancy (``EnergyModel.discrepancy_rel_sd``: the relative standard
deviation of a whole run's energy beyond any coefficient values, calibrated or a priori), and
adds small zero-mean effects the simulator has and the model does not (``DISCREPANCY``):

    theta_true = m_run x theta_draw
    theta_draw ~ N(theta, Cov), truncated at 0 (a coefficient never changes sign)
    m_run ~ N(1, discrepancy_rel_sd^2), truncated at 0: every term is linear in its
        coefficient and the no-recovery clip is scale-free, so the run's power, hence its
        energy, scales by m_run exactly
    wind gusts: Ornstein-Uhlenbeck, std = gust_fraction x mean wind speed, tau = gust_tau_s
    terrain roughness: crr perturbation, std = roughness_fraction x default crr, correlated
        over roughness_length_m (ground robots only)

The truth's energy is then distributed as the reserve assumes (``predictive_variance_J2``:
``g' Cov g + (discrepancy_rel_sd E)^2``), plus the small gust/roughness effects.

Everything else is the scenario's (battery, map, mean wind): the truth has the usable energy
the planner assumes. ``Truth`` objects are what ``sim.simulator.simulate`` (and
``orange-plan simulate --truth``) take.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from orange_plan.errors import InputError
from orange_plan.sim.truth import Truth, Wind

if TYPE_CHECKING:
    from orange_plan.context import Context


@dataclass(frozen=True)
class Discrepancy:
    """Run-to-run effects beyond the coefficients' uncertainty (see the module docstring).

    Attributes
    ----------
    gust_fraction : gust std / mean wind speed [-]
    gust_tau_s : gust correlation time [s]
    roughness_fraction : crr perturbation std / default crr [-]
    roughness_length_m : its correlation length along the path [m]
    run_rel_sd : relative std of the whole-run factor m_run [-]; None: the model's
        ``discrepancy_rel_sd``
    """

    gust_fraction: float = 0.1
    gust_tau_s: float = 10.0
    roughness_fraction: float = 0.05
    roughness_length_m: float = 5.0
    run_rel_sd: float | None = None


DISCREPANCY = Discrepancy()
"""Default discrepancy: the model's run-to-run factor, gusts of 10 % of the mean wind, crr
roughness of 5 % (zero-mean)."""

NONE = Discrepancy(0.0, 10.0, 0.0, 5.0, 0.0)
"""No discrepancy: coefficients only."""


def draw_coefficients(model, n: int, rng) -> list[dict[str, float]]:
    """``n`` coefficient sets from N(theta, Cov), truncated at zero (resampled, then clipped).

    Coefficients with zero variance keep their value.
    """
    theta, cov = np.asarray(model.theta, float), np.asarray(model.cov, float)
    draws = rng.multivariate_normal(theta, cov, size=n, method="eigh")
    for _ in range(10):  # resample the few draws with a sign flip (truncated normal)
        bad = np.any((draws < 0) & (theta >= 0), axis=1)
        if not bad.any():
            break
        draws[bad] = rng.multivariate_normal(theta, cov, size=int(bad.sum()), method="eigh")
    draws = np.where(theta >= 0, np.maximum(draws, 0.0), draws)
    return [dict(zip(model.names, map(float, d))) for d in draws]


def run_factors(rel_sd: float, n: int, rng) -> np.ndarray:
    """``n`` whole-run factors from N(1, rel_sd^2), truncated at 0 (resampled) [-]."""
    m = 1.0 + rel_sd * rng.standard_normal(n)
    for _ in range(10):
        bad = m <= 0
        if not bad.any():
            break
        m[bad] = 1.0 + rel_sd * rng.standard_normal(int(bad.sum()))
    return np.maximum(m, 1e-3)


def calibration_truths(ctx: Context, n: int, seed: int = 0,
                       discrepancy: Discrepancy = DISCREPANCY) -> list[Truth]:
    """``n`` truths within the calibration uncertainty of ``ctx.model`` (seeded).

    Parameters
    ----------
    ctx : Context (scenario, world, model with its covariance)
    n : number of truths (>= 1)
    seed : random seed; the same seed gives the same truths
    discrepancy : run-to-run effects added to every truth

    Returns
    -------
    list of Truth, each with ``coefficients`` overrides (covariance draw x run factor) and the
    discrepancy's gusts/roughness

    Raises
    ------
    InputError
        If ``n`` < 1.
    """
    if n < 1:
        raise InputError(f"number of truths n = {n} must be >= 1")
    rng = np.random.default_rng(seed)
    env = ctx.scenario.environment
    gust = discrepancy.gust_fraction * env.wind_speed_mps
    wind = Wind(env.wind_speed_mps, env.wind_from_deg, gust, discrepancy.gust_tau_s, True)
    ground = ctx.scenario.robot.kind == "ground"
    rough = discrepancy.roughness_fraction * ctx.world.default_crr if ground else 0.0
    draws = draw_coefficients(ctx.model, n, rng)
    rel = (getattr(ctx.model, "discrepancy_rel_sd", 0.0) if discrepancy.run_rel_sd is None
           else discrepancy.run_rel_sd)
    factors = run_factors(rel, n, rng) if rel > 0 else np.ones(n)
    return [Truth(coefficients={k: v * m for k, v in c.items()}, wind=wind,
                  roughness_crr_std=rough, roughness_length_m=discrepancy.roughness_length_m)
            for c, m in zip(draws, factors)]


def truth_multipliers(ctx: Context, truth: Truth) -> dict[str, float]:
    """theta_true / theta for each non-zero coefficient (what a truth changes) [-]."""
    return {k: v / ctx.model.coefficient(k) for k, v in truth.coefficients.items()
            if ctx.model.coefficient(k) != 0}
