"""Diagnosis: find the physics a model left out of a recording, model it, show the fit improve.

The problem, apart from how it is solved. A recording gives the battery power ``y(t)`` and the
motion; the scenario's model, its coefficients refitted to the recording (the *baseline*),
predicts ``P(t)``. Where the residual ``y - P`` is larger than noise, some physics is missing.
Find

1. *where*: the time windows, places (surfaces) and operating conditions (speed, grade, yaw
   rate, temperatures...) in which the residual departs from zero;
2. *what*: the smallest set of vocabulary terms (``physics.terms``), absent from the model, whose
   addition explains the residual on data they were not fitted on, each with physically
   signed coefficients, their uncertainties and the share of the residual it explains;
3. the model with those terms, and how much better it predicts (in-sample, held out, and
   the whole run's energy).

How it is solved. Every term is linear in its coefficients once the no-recovery clip is held
at the baseline's mask (``EnergyModel.power_jacobian``): the baseline's columns ``J`` and a
candidate's columns ``C`` (its ``power_jacobian`` columns at coefficient 0, or, for effects
that are not a term, a payload step or a wind vector, columns built here) form one linear
design. The exception is ``regen``, whose column is the negative part of the force of the
model it joins: a fit with it puts the chosen terms inside the model (``fitting._fit_with_regen``).
A ``drift`` is a family of shapes of time, the shape chosen by BIC (``effects._drift_effect``); its
step only where a payload's step would not be the same column (``effects._steps_are_payloads``);
a rolling drift's step only where it fits better than a payload's step by a BIC of
``min_bic_evidence`` (``effects._rolling_step_earned``).
Forward selection: each round, every candidate not yet chosen is refitted *together
with* the baseline terms (bounded least squares: coefficients keep their physical sign) on
blocked folds (interleaved time blocks: residuals are autocorrelated, so a fit judged on
neighbouring samples would look better than it is) and judged on the held-out blocks. A
candidate passes only when all of these hold:

* the held-out RMSE falls by at least ``min_gain`` (a share) over the current model, and
  at least ``min_folds`` of the ``n_folds`` folds are no worse (within 0.5 %);
* the term's fitted power has an RMS of at least ``min_effect_share`` of the mean |power|
  (worth a term);
* its strongest coefficient is at least ``min_t`` standard errors from zero, the standard
  errors inflated by the residuals' integrated autocorrelation time
  (``calibrate.autoregressive_inflation``, the whiter of the fits with and without the
  term); a payload's change time is scanned over the run, so its
  bar is raised by ``sqrt(2 ln ln n_eff)`` (``scanned``);
* the Bayesian information criterion, with the *effective* number of samples
  ``n / tau``, falls.

Of those that pass, and (once one passes) the scanned ones refused only by their scan's
price, the round takes the one with the lowest BIC, each scanned parameter charged like a
coefficient; among those within ``min_bic_evidence`` of the lowest, the best held out
(``selection._round_choice``). The scan's price guards against naming a scan's largest t where
nothing is missing; which explanation of a missing effect is the right one is the
criterion's question, and held out a step's time is a coin toss in the fold that hides it.

When no single candidate passes, every pair of candidates is tried, fitted together and judged
as one addition (each member must still be significant and worth a term): two effects can
mask each other, so that neither passes alone. A backward pass then drops any chosen term
the others make redundant, and each chosen term is judged once more, added last to the
others with those inside the model (``selection._confirm``: a found force term moves the clip that
its linear column was built at). Non-linear parameters (the time a payload changes, a wind vector)
are estimated inside each fold on its training blocks only. A found term is reported with the
rivals the recording cannot tell from it (``report._alternatives``): one as good held out in its
place, or one that passes in its place while, side by side, neither passes added last.

Before any of this, the power's delay behind the motion is estimated against the baseline's
columns *and every candidate's* (``build.power_lag_s``): a missing term's transients (an
acceleration's inertia) peak at other moments than the baseline's power, and a delay fitted
to the baseline alone slides the power towards them. The delay is then taken out by whole
samples on the recording and by the remaining fraction on the model's side
(``Design.aligned``), so that a short peak is smoothed once on both sides, not twice on one.

Why it does not invent physics. The baseline terms are refitted first, so a mis-set
coefficient of a term already present is absorbed by that term, not blamed on a new one.
A candidate must predict blocks it never saw, by more than a share of the error, with
coefficients of the physical sign, significant under autocorrelation, and pay for its
parameters in BIC: noise, an autocorrelated disturbance, or a column that carries nothing
(a wrong sensor) fail at least one of these. A null result says so explicitly, with the best
candidate's figures as evidence and what the recording could not have shown: every trial
carries its candidate's detection limit (``selection.detection_limit_W``), the smallest RMS power of
it that would pass its t bar with 95 % probability, so that "nothing found" is read as "nothing above
these sizes", not as "nothing".

A term whose coefficients are all 0 in the scenario counts as left out (a switched-off term),
and can be found.

Every threshold named here is a field of ``DiagnosisSettings`` (``settings``), handed to
``diagnose`` and carried by the design to every stage. The stages, one module each:
``design`` (the records passed between stages), ``build`` (the design of a recording),
``candidates`` with ``effects`` and ``labels`` (what is tried and its columns), ``fitting``,
``selection``, ``report`` and ``pipeline`` (``diagnose``). The user's guide:
docs/guide/diagnosis.md.
"""

from orange_plan.identify.diagnosis.build import build_design, lag_columns, power_lag_s
from orange_plan.identify.diagnosis.candidates import (
    TERM_CANDIDATES,
    candidate_columns,
    candidates,
)
from orange_plan.identify.diagnosis.design import LABEL_CANDIDATE, Candidate, Design, Effect
from orange_plan.identify.diagnosis.effects import drift_of_shape, payload_step
from orange_plan.identify.diagnosis.fitting import Fit, fit_design, polish
from orange_plan.identify.diagnosis.labels import label_lag, labelled_design, surface_labels
from orange_plan.identify.diagnosis.pipeline import Diagnosis, diagnose
from orange_plan.identify.diagnosis.report import (
    AS_GOOD_HELD_OUT,
    MASK_EACH_OTHER,
    Finding,
    improved_model,
    payload_mass_kg,
)
from orange_plan.identify.diagnosis.selection import (
    Selection,
    Trial,
    detection_limit_W,
    judge,
    select,
)
from orange_plan.identify.diagnosis.settings import DEFAULT_SETTINGS, DiagnosisSettings

__all__ = [
    "AS_GOOD_HELD_OUT", "DEFAULT_SETTINGS", "LABEL_CANDIDATE", "MASK_EACH_OTHER",
    "TERM_CANDIDATES", "Candidate", "Design", "Diagnosis", "DiagnosisSettings", "Effect",
    "Finding", "Fit", "Selection", "Trial", "build_design", "candidate_columns", "candidates",
    "detection_limit_W", "diagnose", "drift_of_shape", "fit_design", "improved_model", "judge",
    "label_lag", "labelled_design", "lag_columns", "payload_mass_kg", "payload_step", "polish",
    "power_lag_s", "select", "surface_labels",
]
