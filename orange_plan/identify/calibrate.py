"""Calibration: fit the model's lumped coefficients theta (with covariance) to recordings.

Battery power is linear in theta apart from the no-recovery clip ``max(0, F)`` and the
regen product. The fit is a Gauss-Newton / maximum-a-posteriori least squares:

    minimise  sum_i (P_i - P(state_i; theta))^2 / s2  +  sum_k ((theta_k - theta0_k) / sd0_k)^2

with the Jacobian from ``EnergyModel.power_jacobian`` (the clip acts as a mask, recomputed at
each iterate until it stops changing). ``theta0, sd0`` are the scenario's values and their
a priori standard errors (``[model] stderr`` or ``prior_relative_stderr``): they only matter
for directions the data cannot see (a hover power next to an ancillary power; a coefficient
whose feature is zero in the recording). A zero prior standard error means "no prior".

Physical constraints: every lumped coefficient is >= 0 and a regen efficiency is at most 1
(``physical_bounds``). Each Gauss-Newton step is a bounded linear least-squares problem
(``scipy.optimize.lsq_linear``, bounded-variable LS), so the MAP fit stays in range. A
coefficient the data cannot pin is then held at its prior value with the prior's variance,
and the others are refitted without it (repeated until nothing more is held):

* with a prior (sd0 > 0): its posterior sd is not clearly below the prior sd
  (``> PINNED_SD_RATIO x sd0``: the data add less than about half the prior's information;
  a feature absent from the recording leaves the posterior sd at the prior sd), or it is on a
  bound that the data pull it well through (more than ``MIN_EVIDENCE_SIGMA`` of its sd: only
  the bound explains the value; the data hold something its physics cannot be, another
  term's share or a missing term). A bound the data are consistent with (e.g. a regen
  efficiency of 1.003 +- 0.023) is kept: the coefficient stays there, reported ``clipped``;
* without a prior (an a priori value of 0, e.g. ``turning_torque_W``): its feature is absent
  (a zero column) or cannot be told from the other free features' (variance inflation factor
  above ``MAX_VIF``), or its fitted value is within ``MIN_EVIDENCE_SIGMA`` sd of the a priori
  value (the data do not show the effect). These are held first, one pass before the
  coefficients with a prior are judged. A no-prior coefficient the data pin but would drive
  out of range stays on the bound and is reported as ``clipped``, with its sd from the data
  (not zero).

Honest uncertainties: power residuals are autocorrelated (a controller, a gust, a slope
lasts seconds). The noise variance ``s2`` is the residual variance times an inflation
factor ``tau = B var(block means) / var(residuals)`` (batch means over blocks of
``block_s``), i.e. the integrated autocorrelation time in samples; ``cov_ = (J' J / s2 +
P0^-1)^-1`` over the interior coefficients (``posterior``: conditional on those on a bound,
which get their own ``1 / I_kk``).

Calibration experiments (the paper's):
* wheels-up test: rows with a truthy ``wheels_up`` column have no traction: their speed,
  grade, acceleration and yaw rate are zeroed before the features are computed, so they
  inform only the ``power`` terms (ancillary, sensor rate, hover). The wheels spin (motor
  no-load losses show up as power above the ancillary draw: ``fit_report_.wheels_up_W``).
* sensor-rate sweep: a ``sensor_rate_Hz`` column that varies separates ``ancillary_W``
  (s0 + compute + comm) from ``sensor_W_per_Hz`` (s1); ask for ``terms`` with ``sensor_rate``.
* drive tests per surface: a ``surface`` column (or positions on a map with surfaces) with
  the ``surface_rolling`` term gives one ``rolling_kg_<surface>``; ``surface_crr_`` reports
  the implied rolling coefficient per surface.

Run-to-run discrepancy (what a confidence reserve needs besides ``cov_``): the same motion
draws a different energy from run to run (snow state, traffic, cabin heating...), which no
coefficient values explain. With two or more recordings they are split into
``discrepancy_folds`` groups; each group's whole-run energies are predicted by a fit on the
others (E_i, gradient g_i, that fit's covariance Cov), and

    r_i = (E_recorded,i - E_i) / E_i
    discrepancy_rel_sd_^2 = max(0, mean_i(2 max(r_i, 0)^2 - g_i' Cov g_i / E_i^2))

the upper semi-variance of the held-out relative errors, less the part the coefficient
uncertainty explains. Upper, because a reserve guards against runs drawing *more* than
predicted and energy ratios are skewed that way (r >= -1, unbounded above): on the real
data the plain variance gave reserves exceeded in 6 of 44 Husky and 2 of 16 BMW held-out
runs at p = 0.9 (docs/benchmarks/calibration.md). For a symmetric error both estimate the same variance.
With one recording there is nothing run-to-run to measure and the scenario's
``discrepancy_rel_sd`` (its a priori default) is kept.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import lsq_linear

from orange_plan.errors import InputError
from orange_plan.identify.autocorrelation import (  # noqa: F401 - public here too
    autoregressive_inflation,
    inflation_factor,
)
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.model_builder import model_with_terms
from orange_plan.physics.state import MotionState
from orange_plan.telemetry.state import recording_state, wheels_up


@dataclass(frozen=True)
class FitReport:
    """Fit quality.

    Attributes
    ----------
    rmse_W : RMS power residual of the final fit on all samples [W]
    holdout_rmse_W : RMS residual on held-out time blocks, fitted without them [W]
    energy_error_pct : |predicted - recorded| energy on the held-out blocks, % of recorded
    energy_bias_pct : the same, signed (positive: the model predicts more) [%]
    n_samples, n_holdout : samples used in the final fit / held out for the test
    inflation : residual autocorrelation factor tau applied to the noise variance [-]
    residual_sd_W : sqrt of the residual variance (before inflation) [W]
    iterations : Gauss-Newton iterations of the final fit
    wheels_up_W : mean recorded power over wheels-up rows, NaN without any [W]
    unphysical : coefficients outside their physical range (negative, or a regen
        efficiency above 1); the constrained fit keeps every fitted one in range, so only a
        ``fixed`` scenario value can land here
    held_at_prior : coefficients the data cannot pin, kept at their prior value and variance
        (module docstring)
    clipped : coefficients the data pin beyond their physical range, reported on the bound
    discrepancy_rel_sd : run-to-run relative standard deviation of whole-run energy [-]
        (module docstring)
    discrepancy_runs : held-out recordings it was estimated from (0: the a priori value kept)
    """

    rmse_W: float
    holdout_rmse_W: float
    energy_error_pct: float
    energy_bias_pct: float
    n_samples: int
    n_holdout: int
    inflation: float
    residual_sd_W: float
    iterations: int
    wheels_up_W: float = float("nan")
    unphysical: tuple[str, ...] = ()
    held_at_prior: tuple[str, ...] = ()
    clipped: tuple[str, ...] = ()
    discrepancy_rel_sd: float = float("nan")
    discrepancy_runs: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Samples:
    """Stacked samples of one or more recordings, ready for the fit.

    Attributes
    ----------
    state : per-sample MotionState (wheels-up rows already without traction)
    power_W : recorded power [W]
    dt_s : time weight of each sample for energies (forward interval, 0 across gaps) [s]
    block : (recording index, time block index) label of each sample, for hold-out / batches
    wheels_up : True on wheels-up rows
    """

    state: MotionState
    power_W: np.ndarray
    dt_s: np.ndarray
    block: np.ndarray
    wheels_up: np.ndarray

    def subset(self, mask: np.ndarray) -> Samples:
        return Samples(self.state.take(mask, mask.size), self.power_W[mask], self.dt_s[mask],
                       self.block[mask], self.wheels_up[mask])


def recording_samples(recordings, ctx, n_blocks: int = 10,
                      grade_window_m: float | None = None,
                      yaw_rate_column: str | None = None) -> Samples:
    """Motion states, power and time weights of recordings (``telemetry.state.recording_state``).

    Parameters
    ----------
    recordings : telemetry Recording objects
    ctx : Context (world for crr, surfaces and wind; the scenario's sensor rate)
    n_blocks : equal-time blocks per recording (labels for hold-out)
    grade_window_m : smoothing window of elevation before the grade [m]; None: the
        telemetry default (suits GPS/DEM elevation outdoors; use ~1 m on a lab ramp)
    yaw_rate_column : take the yaw rate from this column instead of ``yaw_rate_radps``
    """
    if not recordings:
        raise InputError("calibrate needs at least one recording")
    states, sizes, power, dt, block, up = [], [], [], [], [], []
    for i, rec in enumerate(recordings):
        state = recording_state(rec, ctx.world, conditions=ctx.conditions,
                                grade_window_m=grade_window_m,
                                yaw_rate_column=yaw_rate_column)
        n = len(rec.frame)
        wheels = wheels_up(rec)
        t = rec.t_s
        step = np.r_[np.diff(t) * rec.interval_ok, 0.0]
        edges = np.linspace(t[0], t[-1], n_blocks + 1)
        states.append(state)
        sizes.append(n)
        power.append(rec.frame["power_W"].to_numpy(float))
        dt.append(step)
        block.append(np.stack([np.full(n, i), np.clip(np.searchsorted(edges, t, "right") - 1,
                                                       0, n_blocks - 1)], axis=1))
        up.append(wheels)
    return Samples(MotionState.concat(states, sizes), np.concatenate(power), np.concatenate(dt),
                   np.concatenate(block), np.concatenate(up))


class Calibrator:
    """Fit a model's coefficients to recordings (scikit-learn style).

    Parameters
    ----------
    terms : vocabulary ids of the model to fit; None: the scenario's model as it is
    fixed : coefficient names held at their scenario values
    holdout_blocks : equal-time blocks per recording; every ``holdout_every``-th (offset
        half way) is held out for ``holdout_rmse_W`` and ``energy_error_pct``
    holdout_every : one block in this many is held out (0: no hold-out) [-]
    block_s : batch length for the autocorrelation inflation [s]
    use_prior : include the scenario's a priori values (MAP); False: plain least squares
        (directions the data cannot see then keep their scenario values)
    prior_scale : the a priori standard errors are widened by this factor [-]. Scenario
        values marked "plausible" are rarely within 10 % of a real robot's lumped
        coefficients; widened, they only steer what the data cannot determine
    max_iter : Gauss-Newton iterations
    grade_window_m : elevation smoothing window for the grade [m] (None: telemetry default)
    yaw_rate_column : recording column for the turning feature (None: ``yaw_rate_radps``)
    discrepancy_folds : recordings are split into at most this many groups to estimate the
        run-to-run discrepancy (module docstring); fewer than 2 recordings: not estimated

    Attributes (after ``fit``)
    --------------------------
    model_ : the fitted EnergyModel (theta_ and cov_ inside)
    prior_ : the starting (scenario) coefficients
    theta_ : dict of fitted coefficients
    cov_ : covariance in ``model_.names`` order
    stderr_ : dict of standard errors
    fit_report_ : FitReport
    discrepancy_rel_sd_ : run-to-run relative standard deviation of whole-run energy [-]
        (also ``model_.discrepancy_rel_sd``)
    surface_crr_ : implied rolling coefficient per surface seen in the data (and "default")
    """

    def __init__(self, terms: Sequence[str] | None = None, fixed: Sequence[str] = (),
                 holdout_blocks: int = 10, holdout_every: int = 5, block_s: float = 30.0,
                 use_prior: bool = True, prior_scale: float = 10.0, max_iter: int = 30,
                 grade_window_m: float | None = None, yaw_rate_column: str | None = None,
                 discrepancy_folds: int = 5):
        self.terms = terms
        self.fixed = tuple(fixed)
        self.holdout_blocks = holdout_blocks
        self.holdout_every = holdout_every
        self.block_s = block_s
        self.use_prior = use_prior
        self.prior_scale = prior_scale
        self.max_iter = max_iter
        self.grade_window_m = grade_window_m
        self.yaw_rate_column = yaw_rate_column
        self.discrepancy_folds = discrepancy_folds

    # --- public ------------------------------------------------------------------------
    def fit(self, recordings, ctx) -> Calibrator:
        """Fit to telemetry Recordings in the scenario's world; returns self."""
        self._validate()
        samples = recording_samples(list(recordings), ctx, self.holdout_blocks,
                                    self.grade_window_m, self.yaw_rate_column)
        return self.fit_samples(samples, model_with_terms(ctx, self.terms), ctx.scenario,
                                ctx.world.map.surface_names)

    def fit_samples(self, samples: Samples, model: EnergyModel, scenario=None,
                    surface_names: Sequence[str] = ()) -> Calibrator:
        """Fit to prepared Samples starting from ``model`` (its theta and cov are the prior)."""
        self._validate()
        unknown = [n for n in self.fixed if n not in model.names]
        if unknown:
            raise InputError(f"fixed names unknown coefficient '{unknown[0]}' (have {list(model.names)})")
        if samples.power_W.size < len(model.names) + 2:
            raise InputError(f"{samples.power_W.size} samples are too few to fit "
                             f"{len(model.names)} coefficients")
        held = self._held_out(samples)
        ho_rmse, ho_err, ho_bias = float("nan"), float("nan"), float("nan")
        if held.any() and (~held).any():
            train = self._solve(samples.subset(~held), model).model
            test = samples.subset(held)
            resid = test.power_W - np.asarray(train.power_W(test.state), float)
            ho_rmse = float(np.sqrt(np.mean(resid**2)))
            e_rec = float(np.sum(test.power_W * test.dt_s))
            e_pred = e_rec - float(np.sum(resid * test.dt_s))
            ho_bias = 100.0 * (e_pred - e_rec) / e_rec if e_rec else float("nan")
            ho_err = abs(ho_bias)
        solution = self._solve(samples, model)
        disc, disc_runs = self._discrepancy(samples, model, solution.model.theta)
        fitted = solution.model.with_discrepancy(disc)
        noise = solution.noise
        resid = samples.power_W - np.asarray(fitted.power_W(samples.state), float)
        up = samples.wheels_up
        self.prior_ = model.as_dict()
        self.model_ = fitted
        self.discrepancy_rel_sd_ = disc
        self.theta_ = fitted.as_dict()
        self.cov_ = fitted.cov
        self.stderr_ = fitted.stderr()
        self.fit_report_ = FitReport(
            rmse_W=float(np.sqrt(np.mean(resid**2))), holdout_rmse_W=ho_rmse,
            energy_error_pct=ho_err, energy_bias_pct=ho_bias, n_samples=int(resid.size),
            n_holdout=int(held.sum()), inflation=noise[1], residual_sd_W=float(np.sqrt(noise[0])),
            iterations=solution.iterations,
            wheels_up_W=float(np.mean(samples.power_W[up])) if up.any() else float("nan"),
            unphysical=unphysical(self.theta_), held_at_prior=solution.held,
            clipped=solution.clipped, discrepancy_rel_sd=disc,
            discrepancy_runs=disc_runs)
        self.surface_crr_ = (surface_crr(fitted, samples.state, scenario, surface_names)
                             if scenario else {})
        return self

    # --- internals -----------------------------------------------------------------------
    def _validate(self) -> None:
        if int(self.holdout_blocks) != self.holdout_blocks or self.holdout_blocks < 1:
            raise InputError(f"holdout_blocks = {self.holdout_blocks!r} must be a positive integer")
        if self.holdout_every < 0 or int(self.holdout_every) != self.holdout_every:
            raise InputError(f"holdout_every = {self.holdout_every!r} must be an integer >= 0")
        if not (self.prior_scale > 0 and np.isfinite(self.prior_scale)):
            raise InputError(f"prior_scale = {self.prior_scale!r} must be a positive number")
        if not self.block_s > 0:
            raise InputError(f"block_s = {self.block_s!r} must be > 0")
        if int(self.discrepancy_folds) != self.discrepancy_folds or self.discrepancy_folds < 2:
            raise InputError(f"discrepancy_folds = {self.discrepancy_folds!r} must be an integer "
                             ">= 2")

    def _discrepancy(self, samples: Samples, model: EnergyModel,
                     start: np.ndarray) -> tuple[float, int]:
        """Run-to-run relative sd from recordings held out in groups (module docstring);
        (the model's a priori value, 0) with fewer than two recordings. Sets
        ``discrepancy_residuals_`` (r_i) and ``discrepancy_param_rel_var_`` (g_i' Cov g_i / E_i^2).
        The group fits start from ``start`` (the fit on all data: fewer iterations)."""
        runs = np.unique(samples.block[:, 0])
        k = min(len(runs), int(self.discrepancy_folds))
        self.discrepancy_residuals_ = np.zeros(0)
        self.discrepancy_param_rel_var_ = np.zeros(0)
        if k < 2:
            return model.discrepancy_rel_sd, 0
        resid, param_var = [], []
        for group in range(k):
            held = np.isin(samples.block[:, 0], runs[group::k])
            fitted = self._solve(samples.subset(~held), model, start).model
            for run in runs[group::k]:
                test = samples.subset(samples.block[:, 0] == run)
                jac = fitted.power_jacobian(test.state)
                predicted = float(np.asarray(fitted.power_W(test.state), float) @ test.dt_s)
                if predicted <= 0:  # no energy to be relative to (a run standing still)
                    continue
                recorded = float(test.power_W @ test.dt_s)
                resid.append((recorded - predicted) / predicted)
                param_var.append(float(fitted.energy_variance_J2(test.dt_s @ jac)) / predicted**2)
        if not resid:
            return model.discrepancy_rel_sd, 0
        self.discrepancy_residuals_ = np.array(resid)
        self.discrepancy_param_rel_var_ = np.array(param_var)
        excess = np.mean(2 * np.square(np.maximum(resid, 0.0)) - param_var)
        return float(np.sqrt(max(0.0, excess))), len(resid)

    def _held_out(self, samples: Samples) -> np.ndarray:
        k = int(self.holdout_every)
        if k <= 1:
            return np.zeros(samples.power_W.size, bool)
        return samples.block[:, 1] % k == k // 2

    def _prior(self, model: EnergyModel):
        sd = np.sqrt(np.clip(np.diag(model.cov), 0.0, None)) * self.prior_scale
        informative = (sd > 0) & self.use_prior
        return model.theta.copy(), np.where(informative, sd, np.inf)

    def _solve(self, samples: Samples, model: EnergyModel,
               start: np.ndarray | None = None) -> _Solution:
        """Constrained MAP fit, holding at the prior what the data cannot pin (module
        docstring); each pass holds more, so at most one pass per coefficient."""
        theta0, sd0 = self._prior(model)
        lower, upper = physical_bounds(model.names)
        free = np.array([n not in self.fixed for n in model.names])
        prior_in_range = np.where(free, np.clip(theta0, lower, upper), theta0)
        theta = prior_in_range.copy() if start is None else np.array(start, dtype=float)
        theta = np.where(free, np.clip(theta, lower, upper), theta)
        held = np.zeros(theta.size, bool)
        while True:
            theta[held] = prior_in_range[held]
            fit = free & ~held
            theta, iters, noise_var, noise = self._fit_noise(model, samples, theta, theta0, sd0,
                                                             fit, (lower, upper))
            current = model.with_theta(dict(zip(model.names, theta)))
            jac = current.power_jacobian(samples.state)
            resid = samples.power_W - np.asarray(current.power_W(samples.state), float)
            post = posterior(jac, resid, noise_var, theta, (theta0, sd0), fit, (lower, upper))
            newly = fit & unpinned(post, jac, theta, theta0, sd0, fit)
            if not newly.any():
                break
            # no-prior coefficients first: a collinear one left free blurs the posterior sd
            # of the coefficients with a prior that share its direction
            no_prior = newly & ~np.isfinite(sd0)
            held |= no_prior if no_prior.any() else newly
        # a held coefficient keeps the prior's variance: the scenario's where it gave none
        prior_var = np.where(np.isfinite(sd0), sd0 ** 2, np.clip(np.diag(model.cov), 0.0, None))
        cov = post.cov
        cov[held] = 0.0
        cov[:, held] = 0.0
        cov[held, held] = prior_var[held]
        names = np.array(model.names, dtype=object)
        fitted = model.with_theta(dict(zip(model.names, theta)), cov)
        return _Solution(fitted, iters, noise, tuple(names[held]), tuple(names[post.on_bound]))

    def _fit_noise(self, model, samples, theta, theta0, sd0, fit, bounds):
        """Gauss-Newton fit of the ``fit`` coefficients, re-estimating the noise variance and
        its inflation between passes (they settle in two or three); returns (theta, iterations,
        inflated noise variance, (s2, tau))."""
        y = samples.power_W
        s2, tau, iters = None, 1.0, 0
        for _ in range(3):
            theta, iters = self._gauss_newton(model, samples.state, y, theta, theta0, sd0, fit,
                                              s2 * tau if s2 else None, bounds)
            resid = y - np.asarray(model.power_W(samples.state, theta), float)
            dof = max(1, resid.size - int(fit.sum()))
            s2 = max(float(np.sum(resid**2)) / dof, 1e-12)
            tau = inflation_factor(resid, samples, self.block_s)
        return theta, iters, s2 * tau, (s2, tau)

    def _gauss_newton(self, model, state, y, theta, theta0, sd0, free, noise_var, bounds):
        """Gauss-Newton iterations, each step a bounded linear least-squares problem so that
        every iterate stays within ``bounds`` (lower, upper arrays)."""
        names = model.names
        prior_rows = np.isfinite(sd0) & free
        iters = 0
        if not free.any():
            return theta, iters
        lower, upper = bounds
        for iters in range(1, self.max_iter + 1):  # noqa: B007 - the count is reported
            current = model.with_theta(dict(zip(names, theta)))
            jac = current.power_jacobian(state)[:, free]
            resid = y - np.asarray(current.power_W(state), float)
            var = noise_var if noise_var else max(float(np.var(resid)), 1e-12)
            a = [jac / np.sqrt(var)]
            b = [resid / np.sqrt(var)]
            if prior_rows.any():
                rows = np.diag(1.0 / sd0[free])[prior_rows[free]]
                a.append(rows)
                b.append(((theta0 - theta) / sd0)[prior_rows])
            A, B = np.vstack(a), np.concatenate(b)
            scale = np.linalg.norm(A, axis=0)
            scale[scale == 0] = 1.0
            # the step in scaled units, bounded so that theta + step stays in range
            step_bounds = ((lower - theta)[free] * scale, (upper - theta)[free] * scale)
            delta = lsq_linear(*reduced_ls(A / scale, B), bounds=step_bounds,
                               method="bvls").x / scale
            step = np.zeros_like(theta)
            step[free] = delta
            theta = np.where(free, np.clip(self._damped(model, state, y, theta, step, theta0,
                                                        sd0, var), lower, upper), theta)
            if np.all(np.abs(step) <= 1e-9 + 1e-7 * np.abs(theta)):
                break
        return theta, iters

    @staticmethod
    def _damped(model, state, y, theta, step, theta0, sd0, var):
        def cost(th):
            r = y - np.asarray(model.power_W(state, th), float)
            prior = np.where(np.isfinite(sd0), (th - theta0) / np.where(np.isfinite(sd0), sd0, 1), 0)
            return float(np.sum(r**2) / var + np.sum(prior**2))

        base = cost(theta)
        for frac in (1.0, 0.5, 0.25, 0.125, 0.0625):
            trial = theta + frac * step
            if cost(trial) <= base:
                return trial
        return theta


def reduced_ls(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A k-row least-squares problem ``(m, r)`` with the same minimiser as ``min |a x - b|``
    over any bounds (``|m x - r|^2`` differs by a constant): from the eigen-decomposition of
    ``a'a``. One row per sample made each bounded step (``lsq_linear``) and a tall QR cost
    seconds on a 10 Hz car trip; this costs one ``a'a``. Directions ``a`` does not see get a
    zero row."""
    w, v = np.linalg.eigh(a.T @ a)
    root = np.sqrt(np.clip(w, 0.0, None))
    seen = root > 1e-12 * max(float(root.max()), 1e-300)
    rhs = np.zeros_like(root)
    rhs[seen] = (v.T @ (a.T @ b))[seen] / root[seen]
    return root[:, None] * v.T, rhs


@dataclass(frozen=True)
class _Solution:
    """One constrained fit: the model (theta and cov), Gauss-Newton iterations, noise
    (s2, tau), coefficients held at the prior and coefficients left on a bound."""

    model: EnergyModel
    iterations: int
    noise: tuple[float, float]
    held: tuple[str, ...]
    clipped: tuple[str, ...]


PINNED_SD_RATIO = 0.8
"""A coefficient with a prior is pinned by the data when its posterior sd is below this
fraction of the prior sd: the data then carry at least 1/0.8^2 - 1 = 0.56 times the prior's
information [-]. (0.5, i.e. 3 times, held the ancillary draw of both real data sets in
``bench calibration`` at its prior, 29 +- 16 W against 21 +- 21 W on the Husky, and made
the held-out energy errors slightly worse: docs/benchmarks/calibration.md.)"""
MIN_EVIDENCE_SIGMA = 2.0
"""Evidence threshold in sd (a two-sided 95 % test) [-]: a no-prior coefficient is pinned
only when its fitted value is this far from its a priori value (the effect is there at all);
a coefficient with a prior that the data pull this far through a bound is not explained by
its own physics there."""
MAX_VIF = 1e4
"""A no-prior coefficient whose feature has a variance inflation factor above this among the
free features (R^2 > 0.9999 against the others) cannot be told from them [-]."""


def physical_bounds(names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """Physical range of each lumped coefficient: (lower, upper) arrays.

    Every coefficient is a power, a mass over an efficiency, a drag or a loss coefficient,
    or a fraction: >= 0. A regen efficiency is also at most 1 (no more recovered than spent).
    """
    lower = np.zeros(len(names))
    upper = np.array([1.0 if n == "regen_efficiency" else np.inf for n in names])
    return lower, upper


@dataclass(frozen=True)
class _Posterior:
    """Laplace posterior of one constrained fit: ``cov`` (zero rows outside the fitted
    coefficients), ``sd`` its diagonal's root, ``on_bound`` (coefficients on a bound) and
    ``beyond_sd`` (how many of its own sd the data pull a bound coefficient through its
    bound; 0 elsewhere)."""

    cov: np.ndarray
    sd: np.ndarray
    on_bound: np.ndarray
    beyond_sd: np.ndarray


def posterior(jac: np.ndarray, resid: np.ndarray, noise_var: float, theta: np.ndarray,
              prior, fit: np.ndarray, bounds) -> _Posterior:
    """Laplace posterior of the ``fit`` coefficients at a constrained optimum ``theta``.

    Information ``I = J'J / noise_var + P0^-1``. The interior coefficients get the inverse of
    their block of ``I``: conditional on the bound ones staying on their bounds, which is what
    the constrained fit does (left free, a collinear coefficient on its bound would blur them).
    A coefficient on a bound gets ``1 / I_kk``, the variance its own data give with the
    others held: reported, never zero, uncorrelated with the rest. How far the data pull it
    through the bound is the conditional Newton step from there, ``g_k / I_kk`` with ``g``
    the log-posterior gradient, in units of that sd.
    """
    theta0, sd0 = prior
    lower, upper = bounds
    j = jac[:, fit]
    info = np.zeros((sd0.size, sd0.size))
    info[np.ix_(fit, fit)] = j.T @ j / noise_var + np.diag(1.0 / sd0[fit] ** 2)
    diag = np.diag(info)
    own_var = np.divide(1.0, diag, out=np.full(diag.size, np.inf), where=diag > 0)
    own_sd = np.sqrt(own_var)
    on_bound = fit & at_bound(theta, own_sd, lower, upper)
    interior = fit & ~on_bound
    cov = np.zeros_like(info)
    cov[np.ix_(interior, interior)] = np.linalg.pinv(info[np.ix_(interior, interior)])
    cov[on_bound, on_bound] = own_var[on_bound]
    pull = jac.T @ resid / noise_var + np.where(np.isfinite(sd0), (theta0 - theta) / sd0**2, 0.0)
    outward = np.where(theta - lower <= upper - theta, -pull, pull)
    beyond = np.where(on_bound & np.isfinite(own_sd), outward * np.where(np.isfinite(own_sd),
                                                                           own_sd, 0.0), 0.0)
    return _Posterior(cov, np.sqrt(np.diag(cov)), on_bound, beyond)


def at_bound(theta: np.ndarray, sd: np.ndarray, lower: np.ndarray,
             upper: np.ndarray) -> np.ndarray:
    """True where a coefficient sits on its bound (within a millionth of its sd)."""
    tol = np.minimum(1e-6 * sd, 1e300) + 1e-12 * (1.0 + np.abs(theta))
    return (theta - lower <= tol) | (upper - theta <= tol)


def unpinned(post: _Posterior, jac: np.ndarray, theta: np.ndarray, theta0: np.ndarray,
             sd0: np.ndarray, fit: np.ndarray) -> np.ndarray:
    """Fitted coefficients the data cannot pin (module docstring). With a prior: weakly
    informed, or held on a bound that the data pull it well through. Without: absent,
    collinear, or not told from the a priori value."""
    prior = np.isfinite(sd0)
    weak = prior & (post.sd > PINNED_SD_RATIO * np.where(prior, sd0, np.inf))
    bound_only = prior & (post.beyond_sd > MIN_EVIDENCE_SIGMA)
    vif = np.full(sd0.size, 1.0)
    vif[fit] = variance_inflation(jac[:, fit])
    unseen = ~post.on_bound & (np.abs(theta - theta0) < MIN_EVIDENCE_SIGMA * post.sd)
    return weak | bound_only | (~prior & ((vif > MAX_VIF) | unseen))


def variance_inflation(features: np.ndarray) -> np.ndarray:
    """Variance inflation factor of each column against the others, ``1 / (1 - R^2)`` of
    regressing it on them (no intercept: the ancillary column is one); inf for a zero
    column [-]."""
    norm = np.linalg.norm(features, axis=0)
    out = np.full(norm.size, np.inf)
    ok = norm > 0
    if not ok.any():
        return out
    x = features[:, ok] / norm[ok]
    gram = x.T @ x
    vif = np.empty(int(ok.sum()))
    for k in range(vif.size):
        others = np.arange(vif.size) != k
        g = gram[np.ix_(others, others)]
        c = gram[others, k]
        unexplained = gram[k, k] - c @ np.linalg.pinv(g) @ c if others.any() else 1.0
        vif[k] = 1.0 / max(float(unexplained), 1e-300)
    out[ok] = vif
    return out


def unphysical(theta: dict) -> tuple[str, ...]:
    """Names of coefficients outside their physical range (``physical_bounds``)."""
    names = list(theta)
    lower, upper = physical_bounds(names)
    values = np.array([theta[n] for n in names], dtype=float)
    return tuple(n for n, bad in zip(names, (values < lower) | (values > upper)) if bad)


def surface_crr(model: EnergyModel, state: MotionState, scenario,
                surface_names: Sequence[str] = ()) -> dict[str, float]:
    """Rolling coefficient implied by the fitted rolling coefficients, per surface seen [-].

    ``crr_s = theta_s * Omega / m * mean(crr at those samples)``: theta is m/Omega times
    the ratio of the true to the assumed crr. Key "default" for default ground.
    """
    factor = scenario.omega / scenario.robot.mass_kg
    code = np.broadcast_to(np.asarray(state.surface_code), np.shape(state.speed_mps))
    crr = np.broadcast_to(np.asarray(state.crr, float), code.shape)
    out = {}
    theta = model.as_dict()
    surface_term = next((t for t in model.terms if t.id == "surface_rolling"), None)
    if "rolling_kg" in theta and np.any(code < 0):
        out["default"] = theta["rolling_kg"] * factor * float(np.mean(crr[code < 0]))
    if surface_term is not None:
        for c, name in enumerate(surface_term.coefficients):
            hit = code == c
            if hit.any():
                out[name.removeprefix("rolling_kg_")] = theta[name] * factor * float(np.mean(crr[hit]))
    elif "rolling_kg" in theta:
        for c in np.unique(code[code >= 0]):
            label = surface_names[c] if c < len(surface_names) else f"surface_{int(c)}"
            out[label] = theta["rolling_kg"] * factor * float(np.mean(crr[code == c]))
    return out

