"""The report of a diagnosis: each found term as a ``Finding`` (its parameters as the
scenario knows them, the share of the residual it explains, the evidence, the rivals the
recording cannot tell from it), the sentence of a null result, and the model with the
findings (``improved_model``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from orange_plan.identify.diagnosis.design import (
    LABEL_CANDIDATE,
    Candidate,
    Design,
    _surfaces_seen,
)
from orange_plan.identify.diagnosis.effects import _drift_term_of
from orange_plan.identify.diagnosis.fitting import Fit, _fit_of, fit_design
from orange_plan.identify.diagnosis.labels import label_lag, surface_labels
from orange_plan.identify.diagnosis.selection import Trial, _rivals, judge
from orange_plan.identify.locate import quarters
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.model_builder import SURFACE_PREFIX, make_term, with_payload
from orange_plan.physics.terms import HVAC_SETPOINT_C, hvac_ambient_term
from orange_plan.physics.wind import wind_speed_and_from

AS_GOOD_HELD_OUT = "as good held out"
MASK_EACH_OTHER = "each masks the other"
"""The ``why`` of an ``alternatives`` entry (``_alternatives``)."""


@dataclass(frozen=True)
class Finding:
    """A missing term, named and fitted (a ``missing_physics`` entry of the report,
    docs/guide/diagnosis.md)."""

    term: str
    variant: str | None
    params: dict
    stderr: dict
    explains_pct: float
    evidence: str
    feature_label: str
    alternatives: list = field(default_factory=list)

    def to_dict(self) -> dict:
        out = {"term": self.term, "explains_pct": self.explains_pct, "params": self.params,
               "stderr": self.stderr, "evidence": self.evidence}
        if self.variant:
            out["variant"] = self.variant
        if self.alternatives:
            out["alternatives"] = self.alternatives
        return out


def _finding(d: Design, cand: Candidate, chosen, improved: Fit, baseline: Fit,
             alternatives: list) -> Finding:
    params, stderr = _physical_params(d, improved, cand, *improved.params_of(cand.id))
    without = _fit_of(d, [c for c in chosen if c is not cand])
    ss_base = float(np.sum((d.y - baseline.predicted_W) ** 2))
    ss_gain = float(np.sum((d.y - without.predicted_W) ** 2)
                    - np.sum((d.y - improved.predicted_W) ** 2))
    explains = float(np.clip(100.0 * ss_gain / ss_base, 0.0, 100.0)) if ss_base > 0 else 0.0
    values, label = cand.feature(d)
    evidence = _evidence(d, cand, values, label, baseline, without, improved)
    if cand.id == LABEL_CANDIDATE:
        evidence += ("; the map has no surfaces for these coefficients: the model keeps one "
                     "rolling coefficient (draw the surfaces on the map to plan with them)")
    if alternatives:
        evidence += "; " + ", ".join(_alternative_sentence(a) for a in alternatives) + (
            ": this recording cannot tell them apart")
    return Finding(cand.spec_id, cand.id if cand.id != cand.spec_id else None, params, stderr,
                   explains, evidence, label, alternatives)


def _alternative_sentence(alt: dict) -> str:
    """What an ``_alternatives`` entry says, with the held-out RMSEs it was measured at."""
    rmse = f"{alt['holdout_rmse_W']:.3g} W against {alt['chosen_holdout_rmse_W']:.3g} W"
    if alt["why"] == AS_GOOD_HELD_OUT:
        return f"{alt['term']} in its place predicts the held-out blocks about as well ({rmse})"
    return (f"{alt['term']} in its place passes too ({rmse} held out), and beside it neither "
            "adds anything the other does not explain")


def _alternatives(d: Design, cand: Candidate, chosen, fit: Fit, trials, pool) -> list[dict]:
    """Other candidates the recording cannot tell from ``cand`` (tried: ``_rivals``):

    * ``"why": "as good held out"``: in ``cand``'s place it predicts the held-out blocks
      within ``settings.min_gain`` as well as the chosen set (``fit``);
    * ``"why": "each masks the other"``: in ``cand``'s place it passes diagnosis's test, but
      fitted side by side neither passes added last to the other. A cold battery's loss and
      a payload dropped as the cells warm both fall with time: on development payload seed 9
      the loss was 3 % better held out, the payload passed alone at t = 13, and beside the
      loss (told its true change time) its t fell to 2.7, the loss's to 3.5.

    Each entry gives the held-out RMSE with the rival in ``cand``'s place and with ``cand``
    (both before the final Gauss-Newton polish)."""
    out = []
    rest = [c for c in chosen if c is not cand]
    for other in _rivals(cand, chosen, trials, pool, d.settings.rivals):
        swapped = fit_design(d, [other if c is cand else c for c in chosen])
        if swapped.cv_rmse_W <= fit.cv_rmse_W * (1.0 + d.settings.min_gain):
            why = AS_GOOD_HELD_OUT
        elif _mask_each_other(d, cand, other, rest, fit, swapped):
            why = MASK_EACH_OTHER
        else:
            continue
        out.append({"term": other.spec_id, "why": why,
                    "holdout_rmse_W": float(swapped.cv_rmse_W),
                    "chosen_holdout_rmse_W": float(fit.cv_rmse_W),
                    **({"variant": other.id} if other.id != other.spec_id else {})})
    return out


def _mask_each_other(d: Design, cand: Candidate, other: Candidate, rest: list, fit: Fit,
                     swapped: Fit) -> bool:
    """``other`` passes in ``cand``'s place (``swapped``, against ``rest``), and with both in
    the model neither passes added last to the other (``fit`` has ``cand`` and not
    ``other``)."""
    if not judge(d, [other], swapped, _fit_of(d, rest)).accepted:
        return False
    both = fit_design(d, [*rest, cand, other])
    return (not judge(d, [cand], both, swapped).accepted
            and not judge(d, [other], both, fit).accepted)


def _physical_params(d: Design, fit: Fit, cand: Candidate, params: dict, stderr: dict):
    """Report parameters of the polished fit as the scenario knows them: per-surface rolling
    as the surfaces driven on (``polish`` fits each one's own coefficient), a wind by speed
    and direction (the fitted share left out), a payload as the mass change itself
    (``payload_mass_kg``)."""
    if cand.id == "payload":
        params["payload_kg"], stderr["payload_kg"] = payload_mass_kg(d, fit)
    if cand.id == "surface_rolling":
        seen = {f"{SURFACE_PREFIX}{s}" for s in _surfaces_seen(d)}
        params = {k: v for k, v in params.items() if k in seen}
        stderr = {k: v for k, v in stderr.items() if k in seen}
    if cand.id == LABEL_CANDIDATE:
        params, stderr = _label_params(d, fit, params, stderr)
    if cand.id == "wind":
        params.pop("wind_share", None)
        stderr.pop("wind_share", None)
        params.pop("wind_change_mps", None)
        stderr.pop("wind_change_mps", None)
    return params, stderr


def _label_params(d: Design, fit: Fit, params: dict, stderr: dict):
    """Per-label rolling as ``rolling_kg_<label>`` [kg] from the polished fit (``absorb``:
    the labels as the model's surfaces), the reference label's being ``rolling_kg``; the
    labels' delay ``label_lag_s`` [s] as ``label_lag`` found it on the whole run."""
    labels = surface_labels(d)
    own, reference = labels.own, labels.reference
    base = fit.names.index("rolling_kg")
    out = {f"rolling_kg_{reference}": float(fit.theta[base])}
    sds = {f"rolling_kg_{reference}": float(fit.sd[base])}
    for label in own:
        name = f"rolling_kg_{label}"
        if name in params:
            out[name], sds[name] = params[name], stderr[name]
    lag = label_lag(d, np.ones(d.n, bool))
    out["label_lag_s"], sds["label_lag_s"] = lag.lag_s, lag.sd_s
    return out, sds


def payload_mass_kg(d: Design, fit: Fit) -> tuple[float, float]:
    """The mass change [kg] (and its standard error) that the fitted payload step stands for.

    The step's column is the power per kg at the baseline's refit coefficients, which had
    taken the run's *average* mass (a drone's hover power 63 W for 48.6 W before a 30 %
    payload), so its coefficient is not yet kilograms: the mass change is the one whose
    power, on the joint fit's model (the mass before the change) through
    ``model_builder.with_payload`` (hover as mass^1.5), matches the fitted step after the
    change time in least squares. Its standard error is the coefficient's, scaled alike."""
    from scipy.optimize import minimize_scalar

    own, sd = fit.params_of("payload")
    after = d.t_s >= own["payload_from_s"]
    step_W = fit.contribution_W("payload")[after]
    before = d.base.with_theta({n: float(fit.theta[fit.names.index(n)]) for n in d.base.names})
    mass = d.scenario.robot.mass_kg
    now_W = d.aligned(before.power_W(d.state))[after]

    def mismatch(kg: float) -> float:
        carried = d.aligned(with_payload(before, mass, kg).power_W(d.state))[after]
        return float(np.sum((carried - now_W - step_W) ** 2))

    lo, hi = -0.8 * mass, 2.0 * mass
    kg = float(minimize_scalar(mismatch, bounds=(lo, hi), method="bounded",
                               options={"xatol": 1e-6 * mass}).x)
    linear = own["payload_kg"]
    return kg, float(sd["payload_kg"] * abs(kg / linear)) if linear else float(sd["payload_kg"])


def _evidence(d: Design, cand: Candidate, values, label, baseline: Fit, without: Fit,
              improved: Fit) -> str:
    """One checkable sentence: the residual where the feature is high vs low, and the
    held-out RMSE with and without the term."""
    resid = d.y - baseline.predicted_W
    arr = np.broadcast_to(np.asarray(values, float), (d.n,))
    hi, lo = quarters(arr)
    if not (hi.any() and lo.any()):
        contrast = ""
    else:
        contrast = (f"the baseline's residual averages {np.mean(resid[hi]):+.3g} W in the top "
                    f"quarter of {label} and {np.mean(resid[lo]):+.3g} W in the bottom quarter; ")
    return (f"{cand.id}: {contrast}adding it takes the held-out RMSE from "
            f"{without.cv_rmse_W:.3g} W to {improved.cv_rmse_W:.3g} W")


def _null_evidence(d: Design, baseline: Fit, trials: list[Trial]) -> str:
    best = max(trials, key=lambda t: t.gain, default=None)
    base = (f"the refitted model leaves a residual of {baseline.rmse_W:.3g} W RMS "
            f"({100 * baseline.rmse_W / max(d.mean_power_W, 1e-9):.1f} % of the mean "
            f"power), autocorrelation time {baseline.tau:.0f} samples")
    if best is None:
        return base + "; no candidate applies to this recording"
    return (base + f"; the best candidate, {best.id}, would change the held-out RMSE by "
            f"{-100 * best.gain:+.1f} % ({best.reason})" + _limits_sentence(d, trials))


def _limits_sentence(d: Design, trials: list[Trial]) -> str:
    """What the recording could not have shown: the range of the single candidates'
    detection limits, with the most and least sensitive named."""
    limits = [t for t in trials if "+" not in t.id and np.isfinite(t.detectable_W)]
    if not limits:
        return ""
    lo = min(limits, key=lambda t: t.detectable_W)
    hi = max(limits, key=lambda t: t.detectable_W)
    return (f"; a missing effect smaller than its detection limit could go unseen: from "
            f"{lo.detectable_W:.2g} W RMS ({_share_of_mean(d, lo.detectable_W)} of the mean "
            f"power, {lo.id}) to {hi.detectable_W:.2g} W "
            f"({_share_of_mean(d, hi.detectable_W)}, {hi.id})" + _shape_limits(trials))


def _shape_limits(trials: list[Trial]) -> str:
    """The range of each scanned candidate's limits over the shapes or times its scan could
    have chosen (``Trial.detectable_W_by_alternative``, its last round's), the extremes
    named: its one limit is the shape tried's."""
    last = {t.id: t for t in trials if t.detectable_W_by_alternative}
    parts = []
    for ident, trial in last.items():
        finite = [a for a in trial.detectable_W_by_alternative if np.isfinite(a["detectable_W"])]
        if finite:
            lo = min(finite, key=lambda a: a["detectable_W"])
            hi = max(finite, key=lambda a: a["detectable_W"])
            parts.append(f"{ident} {lo['detectable_W']:.2g} W ({_alternative(lo)}) to "
                         f"{hi['detectable_W']:.2g} W ({_alternative(hi)})")
    return "; by the shape or time its scan could choose: " + ", ".join(parts) if parts else ""


def _alternative(alt: dict) -> str:
    """One alternative of a scan in words: a line, a decay, a step or a payload's change."""
    if "drift_span_s" in alt:
        return "a line over the run"
    if "drift_tau_s" in alt:
        return f"a decay of {alt['drift_tau_s']:.0f} s"
    if "drift_from_s" in alt:
        return f"a step at {alt['drift_from_s']:.0f} s"
    return f"a change at {alt['payload_from_s']:.0f} s"


def _share_of_mean(d: Design, power_W: float) -> str:
    """``power_W`` as a percentage of the mean |power|, whole above 100 %."""
    pct = 100.0 * power_W / max(d.mean_power_W, 1e-9)
    return f"{pct:.1f} %" if pct < 100 else f"{pct:.0f} %"


# --- the model with the findings ----------------------------------------------------------------


def _found_term(term_id: str, own: dict, surface_names):
    """The term a finding names, with the shape or set-points it was found at."""
    if term_id in ("drift", "drift_rolling"):
        return _drift_term_of(own, term_id)
    if term_id == "hvac_ambient":
        return hvac_ambient_term(own.get("hvac_heat_below_C", HVAC_SETPOINT_C),
                                 own.get("hvac_cool_above_C", HVAC_SETPOINT_C))
    return make_term(term_id, surface_names)


def improved_model(d: Design, chosen: list[Candidate], fit: Fit,
                   findings: list[Finding]) -> tuple[EnergyModel, dict]:
    """The baseline's terms plus the found terms, at the polished fit's coefficients, and
    the scenario values a non-term finding changes (a wind; a payload as the mass now
    carried, the finding's kilograms).

    Coefficient variances: the joint fit's for fitted ones.
    """
    values = {n: float(v) for n, v in zip(fit.names, fit.theta) if n in d.base.names}
    variances = {n: float(sd) ** 2 for n, sd in zip(fit.names, fit.sd) if n in d.base.names}
    terms = list(d.base.terms)
    changes: dict = {}
    names = d.world.map.surface_names
    for cand in chosen:
        own, own_sd = fit.params_of(cand.id)
        if cand.id == "payload":
            changes["payload_kg"] = next(f.params["payload_kg"] for f in findings
                                         if f.term == "payload")
        elif cand.id == LABEL_CANDIDATE:
            # the map has no surfaces to hang the coefficients on: the finding reports them
            # and the model keeps its one rolling coefficient
            continue
        elif cand.id == "wind":
            speed, from_deg = wind_speed_and_from(own["wind_x_mps"], own["wind_y_mps"])
            # the drag under that wind is the one fitted with it (the baseline's coefficient
            # had taken part of the wind's mean drag)
            values["drag_kg_per_m"] = own["drag_kg_per_m"]
            variances["drag_kg_per_m"] = own_sd["drag_kg_per_m"] ** 2
            changes["environment.wind_speed_mps"] = float(speed)
            changes["environment.wind_from_deg"] = float(from_deg) % 360.0
        else:
            term = _found_term(cand.id, own, names)
            # surface_rolling stands right after rolling (model_builder's order)
            at = [t.id for t in terms].index("rolling") + 1 if term.id == "surface_rolling" \
                else len(terms)
            terms.insert(at, term)
            for c in term.coefficients:
                values[c] = own[c]
                variances[c] = own_sd[c] ** 2
    coeffs = [c for t in terms for c in t.coefficients]
    model = EnergyModel(terms, {c: values[c] for c in coeffs},
                        np.diag([variances[c] for c in coeffs]), omega=d.base.omega,
                        discrepancy_rel_sd=d.base.discrepancy_rel_sd)
    return with_payload(model, d.scenario.robot.mass_kg, changes.get("payload_kg", 0.0)), changes
