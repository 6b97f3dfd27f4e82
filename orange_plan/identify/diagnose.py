"""Diagnosis: find the physics a model left out of a recording, model it, show the fit improve.

The entry point kept where other code imports it: the method lives in the package
``identify.diagnosis``, one module per stage (design, candidates, fitting, selection,
report); its thresholds are a ``DiagnosisSettings``. The user's guide:
docs/guide/diagnosis.md.
"""

from __future__ import annotations

from orange_plan.identify.diagnosis import (
    AS_GOOD_HELD_OUT,
    DEFAULT_SETTINGS,
    LABEL_CANDIDATE,
    MASK_EACH_OTHER,
    TERM_CANDIDATES,
    Candidate,
    Design,
    Diagnosis,
    DiagnosisSettings,
    Effect,
    Finding,
    Fit,
    Selection,
    Trial,
    build_design,
    candidate_columns,
    candidates,
    detection_limit_W,
    diagnose,
    fit_design,
    improved_model,
    judge,
    label_lag,
    labelled_design,
    lag_columns,
    payload_mass_kg,
    payload_step,
    polish,
    power_lag_s,
    select,
    surface_labels,
)
from orange_plan.identify.diagnosis.fitting import _covariance, _solve

__all__ = [
    "AS_GOOD_HELD_OUT", "DEFAULT_SETTINGS", "LABEL_CANDIDATE", "MASK_EACH_OTHER",
    "TERM_CANDIDATES", "Candidate", "Design", "Diagnosis", "DiagnosisSettings", "Effect",
    "Finding", "Fit", "Selection", "Trial", "_covariance", "_solve", "build_design",
    "candidate_columns", "candidates", "detection_limit_W", "diagnose", "fit_design",
    "improved_model", "judge", "label_lag", "labelled_design", "lag_columns",
    "payload_mass_kg", "payload_step", "polish", "power_lag_s", "select", "surface_labels",
]
