"""The records diagnosis passes between its stages: the linear design of a recording against
the baseline model (``Design``), a candidate term (``Candidate``) and its columns on some
training rows (``Effect``); and the small facts of a design every stage reads (bounds,
the landed periods, the surfaces driven on). How the design is built: ``build``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from orange_plan.errors import InputError
from orange_plan.identify.calibrate import Samples
from orange_plan.identify.diagnosis.settings import DEFAULT_SETTINGS, DiagnosisSettings
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.terms import spec_id

LABEL_CANDIDATE = "surface_label"
"""Per-surface rolling read from the recording's ``surface`` labels, where the map has no
surfaces (reported as ``surface_rolling``, variant ``surface_label``)."""


@dataclass
class Design:
    """One recording against the baseline model, as a linear design.

    Attributes
    ----------
    samples : the recording's samples (``calibrate.recording_samples``)
    base : the baseline model, refitted to the recording
    columns : the baseline's Jacobian columns at its coefficients (n, p) [W per unit]
    lower, upper : physical bounds of the baseline coefficients
    prior_mean, prior_weight : the prior on the baseline coefficients: the scenario's values,
        each weighed by one over its stated variance (``settings.prior_scale`` times the a-priori
        standard error, squared) [1/unit^2]
    noise_var : the recording's noise variance times its autocorrelation time, from the
        baseline's fit [W^2]: a fit's ridge is ``prior_weight * noise_var`` (``ridge``), so that
        the prior weighs against squared residuals in W^2 as one over its variance weighs
        against the residuals in units of the noise
    fold : fold index of each sample (interleaved time blocks)
    t_s : time since the start [s]
    airborne : not in the recording's leading or trailing stationary period (landed)
    columns_of : the recording's column names (what the candidates may read)
    scenario, world : the scenario and its world
    lag_s : delay of the recorded power behind the motion, corrected before fitting [s]:
        the recorded power is moved by whole samples, the model's columns are delayed by
        the remaining fraction of a sample (``column_delay``, ``aligned``)
    grade_window_m : elevation smoothing window of the grade [m] (None: the telemetry default)
    settings : the thresholds every stage reads (``DiagnosisSettings``)
    """

    samples: Samples
    base: EnergyModel
    columns: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    prior_mean: np.ndarray
    prior_weight: np.ndarray
    fold: np.ndarray
    t_s: np.ndarray
    airborne: np.ndarray
    columns_of: frozenset
    scenario: object
    world: object
    frame: object = None
    cache: dict = field(default_factory=dict)
    lag_s: float = 0.0
    grade_window_m: float | None = None
    column_delay: float = 0.0
    settings: DiagnosisSettings = DEFAULT_SETTINGS
    noise_var: float = 1.0

    def ridge(self, k: int, noise_var: float | None = None, theta=None) -> np.ndarray:
        """The prior's weights on ``k`` columns, the baseline's first (the others, a
        candidate's, have no prior), against squared residuals in W^2: ``prior_weight`` at
        ``noise_var`` (None: the design's, the baseline's noise) [W^2/unit^2].

        With ``theta`` (the coefficients of a fit), each weight is a Student-t prior's at them
        (``settings.prior_dof`` degrees of freedom, scaled to be as sharp at the prior mean as
        the normal prior): ``1 / (1 + z^2 / (dof + 1))`` times the normal prior's, ``z`` the
        coefficient's distance from the prior mean in prior sd. A fit solved at these weights
        until they settle is the t prior's most probable value (iteratively reweighted least
        squares): near the scenario's value it steers as the normal prior does, where the
        recording is silent; where the recording contradicts it by many sd, it yields.
        """
        scale = self.noise_var if noise_var is None else noise_var
        weight = self.prior_weight * scale
        if theta is not None:
            weight = weight / (1.0 + self.prior_z2(theta) / (self.settings.prior_dof + 1.0))
        return np.r_[weight, np.zeros(k - weight.size)]

    def prior_z2(self, theta) -> np.ndarray:
        """Each baseline coefficient's squared distance from the prior mean in prior sd
        (``theta``'s first coefficients; a candidate's after them have no prior) [-]."""
        theta = np.asarray(theta, float)
        if theta.size < self.prior_weight.size:
            raise ValueError(f"{theta.size} coefficients for a prior on {self.prior_weight.size}")
        return (theta[:self.prior_weight.size] - self.prior_mean) ** 2 * self.prior_weight

    def aligned(self, values) -> np.ndarray:
        """Model-side values (columns, powers) delayed by ``column_delay`` of a sample, by
        linear interpolation, the first sample held.

        Why the model side: a meter that reports the power a fraction of a sample late
        reports an interpolation of it, which smooths a short peak (a turn, a start). Moving
        the recording back by another interpolation smooths it twice, and a peaked column
        fitted to a twice-smoothed power comes out 2-5 % low (turning, inertia); delaying the
        columns by the same fraction smooths them as the meter smoothed the power."""
        v = np.broadcast_to(np.asarray(values, float), (self.n, *np.shape(values)[1:]))
        f = self.column_delay
        if not f:
            return v
        return (1.0 - f) * v + f * np.concatenate([v[:1], v[:-1]])

    @property
    def mean_power_W(self) -> float:
        """Mean |recorded power|: the yardstick of every "share of the power" test [W]."""
        return float(np.mean(np.abs(self.y)))

    @property
    def y(self) -> np.ndarray:
        return self.samples.power_W

    @property
    def offset(self) -> np.ndarray:
        """``P(theta_b) - J theta_b`` [W]: what the linearisation misses of the baseline's
        power (0 for terms linear in theta; the regen product and the in-battery loss are
        not), so the design is a Gauss-Newton step: ``y - offset ~ J theta + C beta``."""
        if "offset" not in self.cache:
            power = self.aligned(np.asarray(self.base.power_W(self.state), float))
            self.cache["offset"] = power - self.columns @ self.base.theta
        return self.cache["offset"]

    @property
    def target(self) -> np.ndarray:
        """The recorded power less the linearisation offset: what the design regresses [W]."""
        return self.y - self.offset

    @property
    def state(self):
        return self.samples.state

    @property
    def n(self) -> int:
        return self.y.size

    @property
    def rolling_column(self) -> np.ndarray:
        """The baseline's rolling column: power per unit of its ``rolling_kg`` [W/kg], what a
        per-surface, labelled or drifting rolling coefficient scales."""
        return self.columns[:, self.base.names.index("rolling_kg")]


@dataclass(frozen=True)
class Alternatives:
    """The column a one-coefficient effect would have had at each other value its scan
    could have chosen (a drift's shapes, a payload's change times): ``params`` one dict per
    alternative, in the finding's parameter names (``drift_tau_s``, ``payload_from_s``...),
    and ``columns()`` their columns on all samples (n, alternatives) [W per unit], built only
    when asked (the detection limit per alternative, ``selection.limits_by_alternative``)."""

    params: tuple[dict, ...]
    columns: Callable[[], np.ndarray]


@dataclass(frozen=True)
class Effect:
    """A candidate's columns on one set of training rows.

    Attributes
    ----------
    columns : (n, k) power per unit of each linear coefficient [W per unit]
    names : the linear coefficients' names
    lower, upper : their physical bounds
    extra : non-linear parameters estimated on the training rows (payload time, wind) with
        their standard errors: name -> (value, sd)
    sd_scale : per linear coefficient, the factor its standard error grows by once the
        uncertainty of the non-linear parameters it was fitted at is counted (None: 1; an
        HVAC's set-points, ``effects._hvac_ambient_effect``)
    scanned : how many non-linear parameters were chosen by a scan or a search on the
        training rows (a payload's change time, a drift's shape, an HVAC's moved set-points,
        a label's delay and window, a wind's two components): each is charged like a
        coefficient by the information criterion (``fitting.Fit.bic``)
    alternatives : the column at the scan's other choices (``Alternatives``), on the effect
        fitted on all samples of a drift or a payload; None otherwise
    """

    columns: np.ndarray
    names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    extra: dict = field(default_factory=dict)
    sd_scale: np.ndarray | None = None
    scanned: int = 0
    alternatives: Alternatives | None = None


@dataclass(frozen=True)
class Candidate:
    """A vocabulary term (or a variant) tried against the residual.

    Attributes
    ----------
    id : the candidate's own id (a ``physics.terms`` id, or ``wind`` / ``payload``)
    applies : ``applies(design) -> reason it cannot apply, or None``
    effect : ``effect(design, residual, rows) -> Effect`` (rows: the training samples)
    feature : ``feature(design) -> (values, label)``: what a person would plot the residual
        against
    """

    id: str
    applies: Callable
    effect: Callable
    feature: Callable

    @property
    def spec_id(self) -> str:
        return spec_id(self.id)


# --- bounded least squares on Gram matrices ----------------------------------------------



def _baseline_model(ctx) -> EnergyModel:
    """The scenario's model without terms whose coefficients are all 0 (left out)."""
    model = ctx.model
    keep = [t for t in model.terms
            if any(model.coefficient(c) != 0 for c in t.coefficients) or t.id == "regen"]
    theta = {c: model.coefficient(c) for t in keep for c in t.coefficients}
    if not keep:
        raise InputError("the scenario's model has no term with a non-zero coefficient")
    reduced = model.with_terms(keep, theta)
    return reduced


def _bounds(names) -> tuple[np.ndarray, np.ndarray]:
    """Physical ranges of lumped coefficients: every one >= 0, a regen efficiency <= 1."""
    lower = np.zeros(len(names))
    upper = np.array([1.0 if n == "regen_efficiency" else np.inf for n in names])
    return lower, upper


def _airborne(recording, landed_min_s: float) -> np.ndarray:
    """Everything but the leading and trailing stationary periods (a flight log starts and
    ends on the ground), when those last at least ``landed_min_s`` [s]."""
    v = np.abs(recording.frame["v_mps"].to_numpy(float))
    t = recording.t_s
    moving = np.flatnonzero(v > 0.05)
    out = np.ones(v.size, bool)
    if moving.size == 0:
        return out
    first, last = moving[0], moving[-1]
    if t[first] - t[0] >= landed_min_s:
        out[:first] = False
    if t[-1] - t[last] >= landed_min_s:
        out[last + 1:] = False
    return out


def _surfaces_seen(d: Design, share: float = 0.05) -> list[str]:
    """The map surfaces driven on for at least ``share`` of the moving samples."""
    code = np.broadcast_to(np.asarray(d.state.surface_code), (d.n,))
    moving = np.asarray(d.state.speed_mps) > 0
    return [s for i, s in enumerate(d.world.map.surface_names)
            if np.count_nonzero((code == i) & moving) >= share * max(1, moving.sum())]
