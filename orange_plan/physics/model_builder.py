"""The one model builder: term ids -> terms, physical scenario values <-> lumped coefficients,
values -> a prior covariance.

Every EnergyModel made from a scenario goes through here: ``load_context`` and the service
(``build_model``: the reference terms + ``[model]``), calibration and the online
benchmarks (``model_with_terms``: another term list on top of a loaded model), and the
calibrated-scenario writer (``physical_values``: the same table read backwards). So the
``calibrate -o`` round trip holds by construction: what is written is read by the same rows.

The table ``LUMPED`` holds, per lumped coefficient, the physical value it stands for and the
factors between them: ``lumped = value * mul / div`` and ``physical = lumped * div / mul``
(kept as a product and a quotient, not a folded factor, so the forward map gives the very
floats ``(s0 + compute + comm) / (1 - eta_4)`` or ``m / Omega`` of the term table in
docs/guide/range.md).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from orange_plan.errors import InputError, ScenarioError, close_match_hint
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.terms import (
    DEFAULT_REGEN_EFFICIENCY,
    REFERENCE_TERM_IDS,
    TERMS,
    Term,
    drift_rolling_term,
    drift_term,
    hvac_ambient_term,
    surface_rolling_term,
)

SURFACE_PREFIX = "rolling_kg_"
"""Per-surface rolling coefficients ``rolling_kg_<surface>`` share the ``rolling_kg`` row."""


def _one(_scenario) -> float:
    return 1.0


def _omega(scenario) -> float:
    return scenario.omega


def _mass(scenario) -> float:
    return scenario.robot.mass_kg


def _ancillary_keep(scenario) -> float:
    return 1.0 - scenario.losses.ancillary


def _constant(value: float) -> Callable:
    return lambda _scenario: value


@dataclass(frozen=True)
class Lumped:
    """One lumped coefficient read from (and back into) a physical scenario value.

    Attributes
    ----------
    physical : dotted scenario key (``robot.hover_W``) or descriptive name of the physical
        reading; None: no physical reading is reported (an a priori value only)
    value : the scenario's physical value
    mul, div : ``lumped = value * mul / div``
    mass : the coefficient scales with the moving mass (a payload changes it)
    """

    physical: str | None
    value: Callable
    mul: Callable = _one
    div: Callable = _one
    mass: bool = False

    def lumped(self, scenario) -> float:
        return self.value(scenario) * self.mul(scenario) / self.div(scenario)

    def read(self, theta: float, scenario) -> float:
        return theta * self.div(scenario) / self.mul(scenario)


LUMPED: dict[str, Lumped] = {
    "ancillary_W": Lumped(
        "ancillary_load_W",
        lambda s: s.ancillary.s0_W + s.ancillary.compute_W + s.ancillary.comm_W,
        div=_ancillary_keep),
    "sensor_W_per_Hz": Lumped("ancillary.s1_W_per_Hz", lambda s: s.ancillary.s1_W_per_Hz,
                              div=_ancillary_keep),
    "hover_W": Lumped("robot.hover_W", lambda s: s.robot.hover_W),
    # the physical reading of rolling is the factor on the scenario's crr
    "rolling_kg": Lumped("crr_factor", _one, mul=_mass, div=_omega, mass=True),
    "drag_kg_per_m": Lumped("robot.drag_coeff_kg_per_m", lambda s: s.robot.drag_coeff_kg_per_m,
                            div=_omega),
    "grade_kg": Lumped("mass_from_grade_kg", _mass, div=_omega, mass=True),
    "inertia_kg": Lumped("mass_from_inertia_kg", _mass, div=_omega, mass=True),
    "turn_J_per_rad": Lumped("robot.turn_coeff_W_s_per_rad",
                             lambda s: s.robot.turn_coeff_W_s_per_rad),
    "regen_efficiency": Lumped("regen_efficiency", _constant(DEFAULT_REGEN_EFFICIENCY)),
    # motor-current terms: free wheel speed ~ the top speed; no a priori scrub (0: no prior)
    "rolling_torque_kg_mps": Lumped(None, lambda s: s.robot.v_max_mps, mul=_mass, div=_omega,
                                    mass=True),
    "turning_torque_W": Lumped(None, _constant(0.0)),
    # cabin HVAC on the traction battery's bus; no a priori warm-up (0: no prior)
    "hvac_fraction": Lumped(None, _constant(1.0)),
    "drift_W": Lumped(None, _constant(0.0)),
    "drift_rolling_kg": Lumped(None, _constant(0.0)),
    # the heater request is a demand: no a priori share (0: no prior, calibrate it)
    "heater_fraction": Lumped(None, _constant(0.0)),
    # found by diagnosis (identify/diagnosis/); no a priori value (0: no prior)
    "hvac_heat_W_per_K": Lumped(None, _constant(0.0)),
    "hvac_cool_W_per_K": Lumped(None, _constant(0.0)),
    "battery_loss_per_W": Lumped(None, _constant(0.0)),
    "battery_cold_loss_per_W_K": Lumped(None, _constant(0.0)),
}
"""Lumped coefficient -> its physical value (module docstring); one row per coefficient of
``physics.terms.TERMS``."""


def _row(name: str) -> Lumped:
    return LUMPED["rolling_kg" if name.startswith(SURFACE_PREFIX) else name]


def is_mass_coefficient(name: str) -> bool:
    """A lumped coefficient that scales with the moving mass (a payload changes it)."""
    return _row(name).mass if name in LUMPED or name.startswith(SURFACE_PREFIX) else False


HOVER_MASS_EXPONENT = 1.5
"""Hover power grows as weight^1.5 (momentum theory: induced power ~ T^1.5 / sqrt(rho A))."""


def mass_exponents(names) -> np.ndarray:
    """Power of the mass ratio each coefficient scales with: 1 for the mass-proportional
    ones, ``HOVER_MASS_EXPONENT`` for a hover power, 0 for the rest (so also each one's
    relative change per relative change of mass, at the scenario's mass)."""
    return np.array([1.0 if is_mass_coefficient(n) else
                     HOVER_MASS_EXPONENT if n == "hover_W" else 0.0 for n in names])


def mass_scales(names, ratio: float) -> np.ndarray:
    """Factor on each coefficient when the moving mass is ``ratio`` times the scenario's:
    ``ratio ** mass_exponents``."""
    return float(ratio) ** mass_exponents(names)


def with_payload(model: EnergyModel, mass_kg: float, extra_kg: float) -> EnergyModel:
    """The model carrying ``extra_kg`` more (``mass_scales``), its covariance scaled alike:
    the simulator's payload truth and a payload that diagnosis found.

    Raises
    ------
    InputError
        The extra mass (negative: dropped) leaves no mass.
    """
    if extra_kg == 0:
        return model
    ratio = (mass_kg + extra_kg) / mass_kg
    if ratio <= 0:
        raise InputError(f"payload.extra_kg = {extra_kg} leaves no mass (robot {mass_kg} kg)")
    scale = mass_scales(model.names, ratio)
    return model.with_theta(dict(zip(model.names, model.theta * scale)),
                            model.cov * np.outer(scale, scale))


def reference_value(name: str, scenario) -> float:
    """The a priori lumped value of coefficient ``name`` from the scenario's physical values
    (per-surface rolling coefficients start at ``rolling_kg``)."""
    return _row(name).lumped(scenario)


def physical_values(scenario, model: EnergyModel) -> dict[str, float]:
    """Physical quantities implied by a model's lumped coefficients (the table read
    backwards), keyed by dotted scenario key or descriptive name, in table order."""
    theta = model.as_dict()
    return {row.physical: row.read(theta[name], scenario) for name, row in LUMPED.items()
            if row.physical is not None and name in theta}


def reference_terms_by_physics(scenario) -> dict[str, bool]:
    """Which reference terms the scenario's physical keys switch on, in model order."""
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
    on = reference_terms_by_physics(scenario)
    return [t for t in REFERENCE_TERM_IDS
            if on[t] or any(c in given for c in TERMS[t].coefficients)]


def make_term(term_id: str, surface_names: Sequence[str]) -> Term:
    """The term of vocabulary id ``term_id``; ``surface_rolling`` is built for the
    given surfaces.

    Raises
    ------
    InputError
        Unknown id, or ``surface_rolling`` without surfaces.
    """
    if term_id == "surface_rolling":
        if not surface_names:
            raise InputError("term 'surface_rolling' needs surfaces (map or surface column)")
        return surface_rolling_term(tuple(surface_names))
    if term_id not in TERMS:
        raise InputError(f"unknown term '{term_id}'; known: {', '.join([*TERMS, 'surface_rolling'])}"
                         + close_match_hint(term_id, [*TERMS, "surface_rolling"]))
    return TERMS[term_id]


def prior_variance(value: float, relative_stderr: float) -> float:
    """A priori variance of an uncalibrated value: ``(relative_stderr |value|)^2``."""
    with np.errstate(over="ignore"):
        return float(np.square(relative_stderr * abs(value)))


def build_model(scenario, surface_names: Sequence[str] = (), extra_terms=None) -> EnergyModel:
    """The scenario's EnergyModel: reference terms, then [model] extras, in order.

    Parameters
    ----------
    scenario : a loaded Scenario
    surface_names : the map's surface names, for ``surface_rolling`` (none: it is left out)
    extra_terms : override of ``scenario.model.terms``

    Notes
    -----
    ``surface_rolling`` stands right after ``rolling``. The covariance is diagonal:
    ``model.stderr`` entries where given, else ``prior_variance`` (an a priori uncertainty for
    uncalibrated values). The run-to-run discrepancy is ``model.discrepancy_rel_sd``
    (calibrated, or the a priori default).
    """
    spec = scenario.model
    extras = list(spec.terms if extra_terms is None else extra_terms)
    ids = reference_term_ids(scenario) + [t for t in extras if t != "surface_rolling"]
    if "surface_rolling" in extras and surface_names:
        ids.insert(ids.index("rolling") + 1 if "rolling" in ids else 1, "surface_rolling")
    shaped = {"drift": (drift_term, spec.drift),
              "drift_rolling": (drift_rolling_term, spec.drift_rolling),
              "hvac_ambient": (hvac_ambient_term, spec.hvac_ambient)}
    terms = [shaped[t][0](*shaped[t][1]) if t in shaped and shaped[t][1]
             else make_term(t, surface_names) for t in ids]
    theta = {name: spec.coefficients.get(name, reference_value(name, scenario))
             for term in terms for name in term.coefficients}
    unknown = [n for n in spec.stderr if n not in theta]
    if unknown:
        raise ScenarioError(
            f"{scenario.path}: model.stderr names unknown coefficient '{unknown[0]}'"
            + close_match_hint(unknown[0], theta)
        )
    variance = [spec.stderr[n] ** 2 if n in spec.stderr
                else prior_variance(v, spec.prior_relative_stderr) for n, v in theta.items()]
    for (name, value), var in zip(theta.items(), variance):
        if not (np.isfinite(value) and np.isfinite(var)):
            raise ScenarioError(
                f"{scenario.path}: model coefficient {name} = {value:g} (from the robot, losses "
                "and ancillary values) is too large to compute with; check e.g. robot.mass_kg")
    return EnergyModel(terms, theta, np.diag(variance), omega=scenario.omega,
                       discrepancy_rel_sd=spec.discrepancy_rel_sd)


def model_with_terms(ctx, terms: Sequence[str] | None, surface_names=None) -> EnergyModel:
    """The context's model, or one with exactly ``terms`` (vocabulary ids: docs/guide/range.md) in order.

    Coefficients keep the context model's values and (co)variances; new ones start at the
    scenario's reference values with ``prior_variance`` (zero value: no prior).

    Raises
    ------
    InputError
        An unknown term id, or ``surface_rolling`` without surfaces.
    """
    if terms is None:
        return ctx.model
    names = tuple(surface_names or ctx.world.map.surface_names)
    built = [make_term(t, names) for t in terms]
    have = ctx.model.as_dict()
    new = {name: reference_value(name, ctx.scenario) for term in built
           for name in term.coefficients if name not in have}
    model = ctx.model.with_terms(built, new)
    cov = model.cov.copy()
    rel = ctx.scenario.model.prior_relative_stderr
    for i, name in enumerate(model.names):
        if name in new:
            cov[i, i] = prior_variance(new[name], rel)
    return model.with_theta({}, cov)
