"""Build the EnergyModel a scenario describes (the reference terms of SPEC §7 + [model])."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from orange_plan.errors import ScenarioError, close_match_hint
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.terms import TERMS, Term, surface_rolling_term
from orange_plan.scenario import DEFAULT_REGEN_EFFICIENCY

REFERENCE_COEFFICIENTS = (
    "ancillary_W", "sensor_W_per_Hz", "hover_W", "rolling_kg", "drag_kg_per_m", "grade_kg",
    "turn_J_per_rad",
)


def model_coefficient_names(extra_terms: Iterable[str]) -> set[str]:
    """Coefficient names a scenario's [model] table may set (surface ones by prefix)."""
    names = set(REFERENCE_COEFFICIENTS)
    for t in extra_terms:
        if t in TERMS:
            names.update(TERMS[t].coefficients)
    return names


MASS_COEFFICIENTS = ("rolling_kg", "grade_kg", "inertia_kg", "rolling_torque_kg_mps")
"""Coefficients proportional to the moving mass (``reference_coefficients``: m / Omega, or
m v_max / Omega for the rolling torque); per-surface ``rolling_kg_<surface>`` too."""


def is_mass_coefficient(name: str) -> bool:
    """A lumped coefficient that scales with the moving mass (a payload changes it)."""
    return name in MASS_COEFFICIENTS or name.startswith("rolling_kg_")


def reference_coefficients(scenario) -> dict[str, float]:
    """Lumped coefficients of the reference model from a scenario's physical values.

    ``ancillary_W = (s0 + compute + comm)/(1 - eta_4)``, ``sensor_W_per_Hz = s1/(1 - eta_4)``,
    ``rolling_kg = grade_kg = inertia_kg = m/Omega``, ``drag_kg_per_m = c/Omega``.
    """
    anc, robot, omega = scenario.ancillary, scenario.robot, scenario.omega
    eta4 = scenario.losses.ancillary
    return {
        "ancillary_W": (anc.s0_W + anc.compute_W + anc.comm_W) / (1.0 - eta4),
        "sensor_W_per_Hz": anc.s1_W_per_Hz / (1.0 - eta4),
        "hover_W": robot.hover_W,
        "rolling_kg": robot.mass_kg / omega,
        "drag_kg_per_m": robot.drag_coeff_kg_per_m / omega,
        "grade_kg": robot.mass_kg / omega,
        "inertia_kg": robot.mass_kg / omega,
        "turn_J_per_rad": robot.turn_coeff_W_s_per_rad,
        "regen_efficiency": DEFAULT_REGEN_EFFICIENCY,
        # motor-current terms: free wheel speed ~ the top speed; no a priori scrub (0: no prior)
        "rolling_torque_kg_mps": robot.mass_kg * robot.v_max_mps / omega,
        "turning_torque_W": 0.0,
        # cabin HVAC on the traction battery's bus; no a priori warm-up (0: no prior)
        "hvac_fraction": 1.0,
        "drift_W": 0.0,
        # the heater request is a demand: no a priori share (0: no prior, calibrate it)
        "heater_fraction": 0.0,
    }


def reference_terms_by_physics(scenario) -> dict[str, bool]:
    """Which reference terms the scenario's physical keys switch on (SPEC §7), in model order."""
    robot, anc = scenario.robot, scenario.ancillary
    return {
        "ancillary": True,
        "sensor_rate": anc.s1_W_per_Hz > 0,
        "hover": robot.hover_W > 0,
        "rolling": robot.kind == "ground" or robot.crr > 0,
        "aero_drag": robot.drag_coeff_kg_per_m > 0,
        "grade": True,
        "turning": robot.turn_coeff_W_s_per_rad > 0,
    }


def reference_term_ids(scenario) -> list[str]:
    """Terms of the reference model that are switched on for this scenario (absent = off).

    A term is on when its physical key says so, or when ``[model]`` sets its coefficient: a
    value given is a term wanted (a calibrated scenario keeps a term whose fitted value has
    no physical key, e.g. a negative drag coefficient).
    """
    given = scenario.model.coefficients
    return [t for t, on in reference_terms_by_physics(scenario).items()
            if on or any(c in given for c in TERMS[t].coefficients)]


def build_model(scenario, surface_names: Sequence[str] = (), extra_terms=None) -> EnergyModel:
    """The scenario's EnergyModel: reference terms, then [model] extras, in order.

    Parameters
    ----------
    scenario : a loaded Scenario
    surface_names : the map's surface names, for ``surface_rolling``
    extra_terms : override of ``scenario.model.terms``

    Notes
    -----
    The covariance is diagonal: ``model.stderr`` entries where given, else
    ``prior_relative_stderr`` x |value| (an a priori uncertainty for uncalibrated values).
    The run-to-run discrepancy is ``model.discrepancy_rel_sd`` (calibrated, or the a priori
    default).
    """
    spec = scenario.model
    extras = list(spec.terms if extra_terms is None else extra_terms)
    ids = reference_term_ids(scenario) + [t for t in extras if t != "surface_rolling"]
    terms: list[Term] = [TERMS[t] for t in ids]
    if "surface_rolling" in extras and surface_names:
        terms.insert(ids.index("rolling") + 1 if "rolling" in ids else 1,
                     surface_rolling_term(tuple(surface_names)))
    defaults = reference_coefficients(scenario)
    theta = {}
    for term in terms:
        for name in term.coefficients:
            fallback = defaults["rolling_kg"] if name.startswith("rolling_kg_") else defaults[name]
            theta[name] = spec.coefficients.get(name, fallback)
    unknown = [n for n in spec.stderr if n not in theta]
    if unknown:
        raise ScenarioError(
            f"{scenario.path}: model.stderr names unknown coefficient '{unknown[0]}'"
            + close_match_hint(unknown[0], theta)
        )
    sd = np.array([spec.stderr.get(n, spec.prior_relative_stderr * abs(v))
                   for n, v in theta.items()], float)
    with np.errstate(over="ignore"):
        variance = np.square(sd)
    for (name, value), var in zip(theta.items(), variance):
        if not (np.isfinite(value) and np.isfinite(var)):
            raise ScenarioError(
                f"{scenario.path}: model coefficient {name} = {value:g} (from the robot, losses "
                "and ancillary values) is too large to compute with; check e.g. robot.mass_kg")
    return EnergyModel(terms, theta, np.diag(variance), omega=scenario.omega,
                       discrepancy_rel_sd=spec.discrepancy_rel_sd)
