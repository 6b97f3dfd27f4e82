"""The whole diagnosis (``diagnose``): build the design, select the candidates, polish the
fit with the found terms inside the model, and report (``Diagnosis``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orange_plan.identify.diagnosis.build import build_design, power_lag_s
from orange_plan.identify.diagnosis.candidates import candidates
from orange_plan.identify.diagnosis.design import Candidate, Design
from orange_plan.identify.diagnosis.fitting import Fit, polish
from orange_plan.identify.diagnosis.report import (
    _alternatives,
    _finding,
    _null_evidence,
    improved_model,
)
from orange_plan.identify.diagnosis.selection import select
from orange_plan.identify.diagnosis.settings import DEFAULT_SETTINGS, DiagnosisSettings
from orange_plan.identify.locate import (
    locate,
    locate_by_condition,
    merge_equal_conditions,
    per_second,
    residual_by_condition,
    residual_by_surface,
)
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.terms import spec_id


@dataclass(frozen=True)
class Diagnosis:
    """What ``diagnose`` found (``to_dict`` is the report's JSON, docs/guide/diagnosis.md):
    the design, the baseline's and the improved fit, the chosen candidates and their
    findings, where the residual departs from zero, every trial, and the model with the
    findings with the scenario values a finding changes."""

    design: Design
    baseline: Fit
    improved: Fit
    chosen: list
    findings: list
    mismatches: list
    conditions: list
    surfaces: list
    trials: list
    verdict: str
    evidence: str
    model: EnergyModel
    scenario_changes: dict

    def summary(self, fit: Fit, terms) -> dict:
        return {"terms": list(terms), "rmse_W": fit.rmse_W, "holdout_rmse_W": fit.cv_rmse_W,
                "energy_error_pct": self.energy_error_pct(fit)}

    def energy_error_pct(self, fit: Fit) -> float:
        """Whole-run energy error of the held-out predictions, % of the recorded energy."""
        dt = self.design.samples.dt_s
        rec = float(np.sum(self.design.y * dt))
        pred = float(np.sum(fit.held_out_W * dt))
        return 100.0 * (pred - rec) / rec if rec else float("nan")

    def contributions_W(self) -> dict[str, np.ndarray]:
        """Each found term's fitted power along the recording, by candidate id [W]."""
        return {cand.id: self.improved.contribution_W(cand.id) for cand in self.chosen}

    def residual_per_second(self):
        """(second edges [s], baseline residual, improved residual): 1 s means [W]."""
        d = self.design
        edges, before, _ = per_second(d.t_s, d.y - self.baseline.predicted_W)
        _, after, _ = per_second(d.t_s, d.y - self.improved.predicted_W)
        return edges, before, after

    def feature_panels(self) -> list[tuple]:
        """What to plot the residual against: ``(label, feature, residual, fitted term or
        None, name)`` per found term (at most three), the residual being the improved model's
        with that term taken out (a partial residual: the term's own signal, not the other
        found terms'); with none found, the baseline's residual against the best candidate's
        feature, nothing fitted."""
        d = self.design
        resid = d.y - self.baseline.predicted_W
        fitted = self.contributions_W() if self.chosen else {}
        panels = []
        for cand in self.chosen[:3]:
            values, label = cand.feature(d)
            partial = d.y - self.improved.predicted_W + fitted[cand.id]
            panels.append((label, np.asarray(values, float), partial, fitted[cand.id], cand.id))
        if panels:
            return panels
        best = max((t for t in self.trials if "+" not in t.id), key=lambda t: t.gain,
                   default=None)  # a single candidate: a pair has no one feature
        cand = next((c for c in candidates() if best and c.id == best.id), None)
        if cand is None:
            return [("time since start [s]", d.t_s, resid, None, "")]
        values, label = cand.feature(d)
        return [(f"{label} (best candidate, not kept)", np.asarray(values, float), resid, None,
                 cand.id)]

    def to_dict(self) -> dict:
        base_terms = [spec_id(t) for t in self.design.base.term_ids]
        added = [f.term for f in self.findings]
        return {
            "verdict": self.verdict,
            "evidence": self.evidence,
            "baseline": self.summary(self.baseline, dict.fromkeys(base_terms)),
            "mismatches": [m.__dict__ for m in self.mismatches],
            "missing_physics": [f.to_dict() for f in self.findings],
            "improved": self.summary(self.improved, dict.fromkeys([*base_terms, *added])),
            "conditions": self.conditions,
            "surfaces": self.surfaces,
            "candidates": [t.__dict__ for t in self.trials],
            "scenario_changes": self.scenario_changes,
            "power_lag_s": self.design.lag_s,
            "grade_window_m": self.design.grade_window_m,
        }


def diagnose(recording, ctx, *, grade_window_m: float | None = None,
             pool: list[Candidate] | None = None,
             settings: DiagnosisSettings = DEFAULT_SETTINGS) -> Diagnosis:
    """Locate the mismatch between a recording and the scenario's model, name the missing
    physics, fit it, and report the fit before and after (the method: ``identify.diagnosis``).

    Parameters
    ----------
    recording : a cleaned telemetry Recording (``telemetry.recording``)
    ctx : the scenario's Context
    grade_window_m : elevation smoothing window for the grade [m] (None: telemetry default)
    pool : candidates to try (default ``candidates()``)
    settings : the thresholds of every stage (default ``DiagnosisSettings()``)

    Returns
    -------
    Diagnosis
    """
    from threadpoolctl import threadpool_limits

    # the design is tall and thin (n x ~20): a BLAS thread per core bought no time alone
    # (turning+payload 0: 2.6-3.2 s on one thread, 2.7-3.1 s on two, at twice the processor
    # time), and beside other work its spinning threads made a diagnosis up to 4x slower
    with threadpool_limits(1, user_api="blas"):
        return _diagnose(recording, ctx, grade_window_m, pool or candidates(), settings)


def _diagnose(recording, ctx, grade_window_m, pool, settings) -> Diagnosis:
    """``diagnose``'s stages, on one BLAS thread."""
    d = build_design(recording, ctx, grade_window_m=grade_window_m, settings=settings)
    selection = select(d, pool)
    if selection.chosen:
        # the delay again, against what was found: every candidate's columns, fitted freely,
        # can imitate a shift (an acceleration's power is the derivative of a steady one),
        # so the first estimate may be off where the found terms' are not; the delay whose
        # selection predicts the held-out blocks better is kept
        lag_s = d.lag_s + power_lag_s(d, recording.t_s, selection.fit.x)
        if abs(lag_s - d.lag_s) > 0.02:
            d2 = build_design(recording, ctx, grade_window_m=d.grade_window_m, lag_s=lag_s,
                              settings=settings)
            again = select(d2, pool)
            if again.fit.cv_rmse_W < selection.fit.cv_rmse_W:
                d, selection = d2, again
    chosen, baseline, trials = selection.chosen, selection.baseline, selection.trials
    improved = polish(d, chosen, selection.fit)
    resid = d.y - baseline.predicted_W
    findings = [_finding(d, c, chosen, improved, baseline,
                         _alternatives(d, c, chosen, selection.fit, trials, pool))
                for c in chosen]
    conditions = residual_by_condition(d, resid, baseline.tau)
    model, scenario_changes = improved_model(d, chosen, improved, findings)
    return Diagnosis(
        design=d, baseline=baseline, improved=improved, chosen=chosen, findings=findings,
        mismatches=merge_equal_conditions(locate(d, resid),
                                          locate_by_condition(d, resid, conditions)),
        conditions=conditions,
        surfaces=residual_by_surface(d, resid), trials=trials,
        verdict="missing physics found" if findings else "no missing physics found",
        evidence=_null_evidence(d, baseline, trials) if not findings else
        "; ".join(f.evidence for f in findings),
        model=model, scenario_changes=scenario_changes)
