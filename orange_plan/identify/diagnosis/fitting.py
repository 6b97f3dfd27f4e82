"""Fitting a design: bounded least squares on blocked folds (``fit_design``, ``Fit``), with
``regen`` inside the model where it is tried, and the Gauss-Newton rounds that put found terms
inside the model (``polish``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import lsq_linear

from orange_plan.identify.calibrate import autoregressive_inflation
from orange_plan.identify.diagnosis.design import (
    LABEL_CANDIDATE,
    Candidate,
    Design,
    _bounds,
    _surfaces_seen,
)
from orange_plan.identify.diagnosis.labels import labelled_design
from orange_plan.physics.model_builder import SURFACE_PREFIX, make_term
from orange_plan.physics.terms import TERMS


def _solve(gram: np.ndarray, rhs: np.ndarray, lower, upper) -> np.ndarray:
    """Bounded least squares from normal equations: ``min x'Gx - 2 b'x`` in ``[lower, upper]``.

    Solved with the columns scaled to unit norm and a tiny ridge for rank deficiency, so each
    fold's solve is k x k however long the recording: directly when no bound is active (the
    unconstrained optimum is then the bounded one), else written as ``|R x - z|^2`` with
    ``R'R = G`` (Cholesky) for bounded-variable least squares. A coefficient whose column is
    all zero on these rows (a surface never driven on) is left at 0 within its bounds: scaled
    by its vanishing norm, rounding error became 1e+280.
    """
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    diag = gram.diagonal()
    live = diag > 1e-24 * max(float(diag.max(initial=0.0)), 1e-300)
    x = np.clip(np.zeros(rhs.size), lower, upper)
    if not live.any():
        return x
    every = live.all()
    if not every:
        gram, rhs = gram[np.ix_(live, live)], rhs[live]
    scale = np.sqrt(gram.diagonal())
    g = gram / np.outer(scale, scale)
    g.flat[::g.shape[0] + 1] += 1e-10
    zs = rhs / scale
    lo, hi = (lower, upper) if every else (lower[live], upper[live])
    lo, hi = lo * scale, hi * scale
    guess = _at_violated_bounds(g, zs, np.linalg.solve(g, zs), lo, hi)
    if guess is not None:
        x[live] = guess / scale
        return x
    r = np.linalg.cholesky(g).T
    x[live] = lsq_linear(r, np.linalg.solve(r.T, zs), bounds=(lo, hi), method="bvls").x / scale
    return x


def _at_violated_bounds(g, z, free, lo, hi):
    """The bounded optimum of ``x'gx - 2 z'x`` if it holds the coefficients whose
    unconstrained optimum ``free`` crosses a bound at that bound, else None: ``free`` itself
    when none crosses; else the others solved with those fixed, accepted where the optimality
    conditions hold (the others within their bounds, and the gradient pushing each fixed one
    outwards). A convex problem's optimum is the point where they hold, and one coefficient
    at 0 is the usual case: bounded-variable least squares, ten times dearer, is left for the
    rest."""
    at_lo, at_hi = free < lo, free > hi
    fixed = at_lo | at_hi
    if not fixed.any():
        return free
    x = np.where(at_lo, lo, np.where(at_hi, hi, 0.0))
    rest = ~fixed
    if rest.any():
        x[rest] = np.linalg.solve(g[np.ix_(rest, rest)], z[rest] - g[np.ix_(rest, fixed)] @ x[fixed])
        if not ((x[rest] >= lo[rest]).all() and (x[rest] <= hi[rest]).all()):
            return None
    grad = g @ x - z
    tol = 1e-9 * (1.0 + float(np.abs(z).max()))
    if (grad[at_lo] >= -tol).all() and (grad[at_hi] <= tol).all():
        return x
    return None


@dataclass(frozen=True)
class Fit:
    """A design fitted on all samples and judged on held-out folds.

    Attributes
    ----------
    theta : coefficients fitted on all samples
    sd : their standard errors, autocorrelation-inflated
    predicted_W : in-sample prediction [W]
    held_out_W : each sample predicted by the fit that did not see its fold [W]
    cv_rmse_W, rmse_W : held-out and in-sample RMSE [W]
    tau : residual autocorrelation inflation [-]
    extra : non-linear parameters (all samples): name -> (value, sd)
    names : coefficient names (baseline, then candidates)
    fold_ss : held-out sum of squared errors per fold [W^2]
    x : the design's columns on all samples (n, k) [W per unit]
    n_scanned : the candidates' non-linear parameters chosen by a scan (``Effect.scanned``)
    alternatives : candidate id -> its effect's ``Alternatives`` (a drift's other shapes, a
        payload's other change times), for those that have them
    ridge : the prior's weight on each coefficient in this fit (``Design.ridge``)
        [W^2/unit^2]
    """

    theta: np.ndarray
    sd: np.ndarray
    predicted_W: np.ndarray
    held_out_W: np.ndarray
    cv_rmse_W: float
    rmse_W: float
    tau: float
    extra: dict
    names: tuple
    fold_ss: np.ndarray
    x: np.ndarray
    n_scanned: int
    alternatives: dict
    ridge: np.ndarray

    def bic(self, tau: float) -> float:
        """Bayesian information criterion with ``n / tau`` effective samples, every
        coefficient and every scanned parameter charged ``ln n_eff``; compare fits at one
        ``tau`` (the reference model's), or a whiter residual would pay for its parameters
        with fewer samples."""
        k = self.theta.size + self.n_scanned
        n_eff = max(self.predicted_W.size / tau, k + 2.0)
        return n_eff * np.log(max(self.rmse_W**2, 1e-300)) + k * np.log(n_eff)

    def owned(self, cand_id: str) -> list[int]:
        """Indices of a candidate's coefficients (named ``<candidate>.<coefficient>``)."""
        return [i for i, name in enumerate(self.names) if name.startswith(f"{cand_id}.")]

    def contribution_W(self, cand_id: str) -> np.ndarray:
        """A candidate's fitted power along the recording [W]."""
        own = self.owned(cand_id)
        return self.x[:, own] @ self.theta[own]

    def effect_rms_W(self, cand_id: str) -> float:
        """RMS of a candidate's fitted power [W]."""
        return float(np.sqrt(np.mean(self.contribution_W(cand_id) ** 2)))

    def params_of(self, cand_id: str) -> tuple[dict, dict]:
        """A candidate's coefficients and non-linear parameters, and their standard
        errors, by their own names (the ``<candidate>.`` prefix dropped)."""
        values = {self.names[i].split(".", 1)[1]: float(self.theta[i])
                  for i in self.owned(cand_id)}
        sds = {self.names[i].split(".", 1)[1]: float(self.sd[i]) for i in self.owned(cand_id)}
        for key, (value, sd) in self.extra.items():
            if key.startswith(f"{cand_id}."):
                values[key.split(".", 1)[1]] = float(value)
                sds[key.split(".", 1)[1]] = float(sd)
        return values, sds


def fit_design(d: Design, chosen: list[Candidate]) -> Fit:
    """Fit the baseline columns plus the chosen candidates' effects (the method:
    ``identify.diagnosis``); with ``regen`` among them, inside the model
    (``_fit_with_regen``)."""
    if any(c.id == "regen" for c in chosen):
        return _fit_with_regen(d, chosen)
    return _linear_fit(d, chosen)


def _fit_with_regen(d: Design, chosen: list[Candidate]) -> Fit:
    """A fit with ``regen`` and the chosen terms *inside* the model (``polish``'s
    Gauss-Newton), so that braking returns ``eff`` of the negative traction power of
    the model the efficiency joins.

    Why not its linear column next to the others: that column is ``-max(0, -F) v`` at
    the *baseline's* force, and a scenario without inertia hardly ever brakes (on the BMW i3
    trips it was zero on every sample: a held-out gain of exactly 0.0 %, t = 0); and an
    inertia column built at that clip is charged on braking samples in full, i.e. returns
    100 % of them, which leaves a regeneration nothing to do. Inside the model the clip is
    the joint force's: braking returns the fitted efficiency, neither 0 nor 100 %.

    Candidates chosen after ``regen`` (a later round's trial) are fitted as columns beside
    that model, built once per set before them (as every candidate is judged beside the
    baseline's linearisation)."""
    at = next(i for i, c in enumerate(chosen) if c.id == "regen") + 1
    key = ("regen_inside", tuple(c.id for c in chosen[:at]))
    if key not in d.cache:
        first = chosen[:at]
        d.cache[key] = absorb(d, first, _linear_fit(d, first), d.settings.regen_rounds)
    absorbed = d.cache[key]
    fit = _linear_fit(absorbed.design, [*absorbed.others, *chosen[at:]])
    return replace(fit, names=absorbed.prefixed(fit.names))


def _reference(d: Design, chosen: list[Candidate], new: list[Candidate], current: Fit) -> Fit:
    """The fit that ``new`` is judged against: ``current`` (the ``chosen`` candidates'), but
    for ``regen`` beside chosen terms, those terms *inside* the model (``polish``), where
    braking returns nothing. Their columns built at the baseline's clip charge braking in
    full, i.e. return 100 % of it, and regeneration judged against that gained 1.2 % on a
    BMW i3 trip whose efficiency is 0.9, against 59 % over inertia that returns nothing."""
    if not any(c.id == "regen" for c in new) or not any(_goes_inside(c) for c in chosen):
        return current
    key = ("inside", tuple(c.id for c in chosen))
    if key not in d.cache:
        d.cache[key] = polish(d, chosen, _fit_of(d, chosen))
    return d.cache[key]


def _goes_inside(cand: Candidate) -> bool:
    """Whether ``polish`` puts a chosen candidate inside the model (a term; not hover, whose
    column idles when landed, nor a drift or an HVAC on the ambient, whose shape or
    set-points are the candidate's)."""
    return ((cand.id in TERMS
             and cand.id not in ("hover", "drift", "drift_rolling", "hvac_ambient"))
            or cand.id in ("surface_rolling", LABEL_CANDIDATE))


def _linear_fit(d: Design, chosen: list[Candidate]) -> Fit:
    """``fit_design`` with every chosen effect as linear columns beside the baseline's, the
    prior weighed at this fit's own noise: fitted first at the baseline's (``d.noise_var``),
    then again at the noise variance times autocorrelation time that fit leaves. The prior
    is a stated standard error on each coefficient; against squared residuals in W^2 its
    weight is the noise's variance over the prior's, so a fit that explains more (a found
    effect) leans less on it, as its residuals say it may."""
    first = _linear_fit_at(d, chosen, d.noise_var)
    return _linear_fit_at(d, chosen, noise_var_W2(first.rmse_W**2, first.tau))


def noise_var_W2(mean_square_W2: float, tau: float) -> float:
    """The noise a prior is weighed at: a residual's mean square times its autocorrelation
    time, kept above 0 for a perfect fit [W^2]."""
    return max(mean_square_W2 * tau, 1e-12)


def _linear_fit_at(d: Design, chosen: list[Candidate], noise_var: float) -> Fit:
    """``_linear_fit`` with the prior weighed at ``noise_var`` [W^2]."""
    n, p = d.columns.shape
    held = np.zeros(n)
    for f in range(d.settings.n_folds):
        train = d.fold != f
        x, lo, hi, _names, _extra = _stack(d, chosen, train)
        theta = _fit_rows(d, x, lo, hi, train, noise_var)
        held[~train] = x[~train] @ theta + d.offset[~train]
    x, lo, hi, names, extra = _stack(d, chosen, np.ones(n, bool))
    theta = _fit_rows(d, x, lo, hi, np.ones(n, bool), noise_var)
    pred = x @ theta + d.offset
    resid = d.y - pred
    tau = autoregressive_inflation(resid, d.samples, d.settings.inflation_block_s)
    s2 = float(np.mean(resid**2))
    ridge = d.ridge(x.shape[1], noise_var, theta)
    gram = x.T @ x + np.diag(ridge)
    cov = np.linalg.pinv(gram / (s2 * tau) if s2 > 0 else gram)
    effects = _all_row_effects(d, chosen)
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None)) * np.concatenate(
        [np.ones(p), *(np.ones(len(e.names)) if e.sd_scale is None else e.sd_scale
                       for e in effects)])
    fold_ss = np.bincount(d.fold, (d.y - held) ** 2, minlength=d.settings.n_folds)
    return Fit(theta, sd, pred, held, float(np.sqrt(np.mean((d.y - held) ** 2))),
               float(np.sqrt(s2)), float(tau), extra, tuple(names), fold_ss, x,
               sum(e.scanned for e in effects),
               {c.id: e.alternatives for c, e in zip(chosen, effects) if e.alternatives},
               ridge)


def _stack(d: Design, chosen, rows):
    """The design's columns on training ``rows``: each candidate's non-linear parameters are
    estimated on the residual of the baseline and the candidates before it, fitted on
    ``rows`` only (so a held-out fold never informs them). (Re-estimating each on the
    residual of all the others, backfitting, changed no found parameter by 0.1 % on the
    wind + payload cases: it is not done.)"""
    rows_key = hash(np.packbits(rows).tobytes())
    effects = []
    for k, cand in enumerate(chosen):
        # the effect depends on the rows and the candidates before it only: a wind fitted on
        # a fold is the same in every later round's trials (its Gauss-Newton is the cost)
        key = ("effect", cand.id, tuple(c.id for c in chosen[:k]), rows_key)
        if key not in d.cache:
            d.cache[key] = cand.effect(d, _residual_without(d, effects, rows), rows)
        effects.append(d.cache[key])
    names, extra = list(d.base.names), {}
    for cand, eff in zip(chosen, effects):
        names += [f"{cand.id}.{nm}" for nm in eff.names]
        extra.update({f"{cand.id}.{k}": v for k, v in eff.extra.items()})
    return (np.hstack([d.columns, *(e.columns for e in effects)]),
            np.concatenate([d.lower, *(e.lower for e in effects)]),
            np.concatenate([d.upper, *(e.upper for e in effects)]), names, extra)


def _all_row_effects(d: Design, chosen) -> list:
    """The chosen candidates' effects fitted on every row (``_stack`` built them), in
    order: their ``sd_scale`` and ``scanned`` describe the fit on all samples."""
    rows_key = hash(np.packbits(np.ones(d.n, bool)).tobytes())
    return [d.cache[("effect", cand.id, tuple(c.id for c in chosen[:k]), rows_key)]
            for k, cand in enumerate(chosen)]


def _residual_without(d: Design, effects, rows) -> np.ndarray:
    """The target less the fit, on ``rows``, of the baseline and ``effects`` [W]."""
    x = np.hstack([d.columns, *(e.columns for e in effects)])
    lo = np.concatenate([d.lower, *(e.lower for e in effects)])
    hi = np.concatenate([d.upper, *(e.upper for e in effects)])
    return d.target - x @ _fit_rows(d, x, lo, hi, rows)


def _fit_rows(d: Design, x, lo, hi, rows, noise_var: float | None = None) -> np.ndarray:
    """The bounded fit of ``x`` on ``rows``, the baseline's coefficients (its first) under the
    Student-t prior weighed at ``noise_var`` (None: the baseline's noise, ``Design.ridge``).

    The t prior's posterior can have two modes where the recording and the prior disagree:
    one near each. Each is found by reweighting (``Design.ridge`` at the solution, until the
    coefficients settle, ``settings.prior_rounds`` at most), one started from the normal
    prior's fit, one from the recording's alone (the prior at a unit noise, next to nothing
    against W^2), and the more probable kept."""
    xr = x[rows]
    gram = xr.T @ xr
    rhs = xr.T @ d.target[rows]
    k = x.shape[1]
    mean = np.r_[d.prior_mean, np.zeros(k - d.prior_mean.size)]
    scale = d.noise_var if noise_var is None else noise_var

    def solve_at(w):
        return _solve(gram + np.diag(w), rhs + w * mean, lo, hi)

    def settle(theta):
        for _ in range(d.settings.prior_rounds):
            new = solve_at(d.ridge(k, scale, theta))
            if (np.abs(new - theta) <= 1e-9 + 1e-6 * np.abs(theta)).all():  # np.allclose's test
                return new
            theta = new
        return theta

    def cost(theta):  # minus the log posterior, in units of the noise
        resid_ss = theta @ gram @ theta - 2 * rhs @ theta
        shape = d.settings.prior_dof + 1.0
        return resid_ss / scale + shape * np.sum(np.log1p(d.prior_z2(theta) / shape))

    # the two starts are one where the prior is already weighed at unit noise
    starts = dict.fromkeys((scale, 1.0))
    return min((settle(solve_at(d.ridge(k, s))) for s in starts), key=cost)


def _covariance(jac: np.ndarray) -> np.ndarray:
    """``(J'J)^+`` with the columns scaled to unit norm first (a Jacobian whose columns differ
    by orders of magnitude, or repeat one another, otherwise gives negative variances from
    rounding); a column that is all zero gets variance 0 [per unit^2]."""
    norm = np.linalg.norm(jac, axis=0)
    scale = np.where(norm > 0, norm, 1.0)
    js = jac / scale
    cov = np.linalg.pinv(js.T @ js, rcond=1e-10, hermitian=True) / np.outer(scale, scale)
    cov[np.diag_indices_from(cov)] = np.clip(np.diag(cov), 0.0, None)
    return cov


def _fit_of(d: Design, chosen: list[Candidate]) -> Fit:
    """``fit_design`` of a set of chosen candidates, kept on the design: the fit without one
    found term is wanted by the backward pass, ``_confirm`` and each finding's evidence."""
    key = ("fit", tuple(c.id for c in chosen))
    if key not in d.cache:
        d.cache[key] = fit_design(d, chosen)
    return d.cache[key]


@dataclass(frozen=True)
class Absorbed:
    """Chosen candidates with the terms among them put inside the model (``absorb``).

    Attributes
    ----------
    design : the design whose model holds the chosen terms
    others : the chosen effects that stay candidates beside it (payload, wind, hover, drift)
    fit : the fit of that design with ``others``
    owner : each coefficient the terms brought in -> the id of the candidate it came from
    """

    design: Design
    others: list
    fit: Fit
    owner: dict

    def prefixed(self, names) -> tuple:
        """``names`` with the ``<candidate>.`` prefix of ``fit_design`` on the coefficients
        the terms brought in."""
        return tuple(f"{self.owner[n]}.{n}" if n in self.owner else n for n in names)


def polish(d: Design, chosen: list[Candidate], fit: Fit, rounds: int = 3) -> Fit:
    """Gauss-Newton rounds with the found terms inside the model: their columns were built at
    the baseline's no-recovery clip, which a found force term moves (an inertia term makes
    braking samples negative force: no power, not negative power). The found terms join the
    baseline's, the Jacobian and the linearisation offset are evaluated at the joint
    estimate, and the fit repeats; effects that are not terms (payload, wind) stay
    candidates. Per-surface rolling joins as the ``surface_rolling`` term: its change
    column was built at the baseline's clip, which on a gentle downhill of a surface that
    rolls harder than the default says "no traction, no power" where the truth draws some
    (a noise-free case came out 24 % low); a surface the recording never drove on keeps the
    default coefficient. Names keep the ``<candidate>.`` prefix of ``fit_design`` (per-surface
    rolling as ``surface_rolling.rolling_kg_<surface>``, no longer a change)."""
    absorbed = absorb(d, chosen, fit, rounds)
    return replace(absorbed.fit, names=absorbed.prefixed(absorbed.fit.names))


def absorb(d: Design, chosen: list[Candidate], fit: Fit, rounds: int = 3) -> Absorbed:
    """``polish``'s Gauss-Newton (``Absorbed``). With no term among ``chosen``: ``d``,
    ``chosen`` and ``fit`` as they are, no owner."""
    # hover stays a candidate: its column is zero on landed samples, its term is not
    inside = [c for c in chosen if _goes_inside(c)]
    if not inside:
        return Absorbed(d, list(chosen), fit, {})
    labelled = any(c.id == LABEL_CANDIDATE for c in inside)
    if labelled:
        d = labelled_design(d)
    others = [c for c in chosen if c not in inside]
    values = dict(zip(fit.names, fit.theta))
    terms = [make_term("surface_rolling" if c.id == LABEL_CANDIDATE else c.id,
                       d.world.map.surface_names) for c in inside]
    owner = {name: c.id for c, t in zip(inside, terms) for name in t.coefficients}
    start = {n: _start_value(values, owner[n], n) for n in owner}
    model = d.base.with_terms([*d.base.terms, *terms], start)
    model = model.with_theta({n: values[n] for n in d.base.names})
    lower, upper = _bounds(model.names)
    # a label has its own coefficient because it covers ``min_label_share`` of the raw
    # labels; its majority may cover a little less, and it is still fitted
    seen = {f"{SURFACE_PREFIX}{s}" for s in _surfaces_seen(d, 1e-3 if labelled else 0.05)}
    # a surface never driven on has an all-zero column: it takes the default coefficient
    unseen = [i for i, n in enumerate(model.names)
              if owner.get(n) in ("surface_rolling", LABEL_CANDIDATE) and n not in seen]
    extra = len(model.names) - len(d.base.names)

    def design_at(model) -> Design:
        return replace(d, base=model, columns=d.aligned(model.power_jacobian(d.state)),
                       lower=lower, upper=upper, prior_mean=np.r_[d.prior_mean, np.zeros(extra)],
                       prior_weight=np.r_[d.prior_weight, np.zeros(extra)], cache={})

    polished = fit
    for _ in range(rounds):
        polished = fit_design(design_at(model), others)
        if unseen:
            default = model.names.index("rolling_kg")
            theta, sd = polished.theta.copy(), polished.sd.copy()
            theta[unseen], sd[unseen] = theta[default], sd[default]
            polished = replace(polished, theta=theta, sd=sd)
        model = model.with_theta(dict(zip(model.names, polished.theta[:len(model.names)])))
    return Absorbed(design_at(model), others, polished, owner)


def _start_value(values: dict, owner: str, name: str) -> float:
    """A found term's coefficient from ``fit_design``'s values; a surface's rolling is the
    default coefficient plus the surface's fitted change."""
    if owner in ("surface_rolling", LABEL_CANDIDATE):
        surface = name.removeprefix(SURFACE_PREFIX)
        return values["rolling_kg"] + values.get(f"{owner}.delta_{name}", 0.0) \
            if surface else values["rolling_kg"]
    return values[f"{owner}.{name}"]


def efficiency_profile(d: Design, chosen: list[Candidate], regen: Candidate, fit: Fit,
                       grid, rounds: int = 3) -> np.ndarray:
    """The deviance of each regeneration efficiency of ``grid``: ``chosen`` and ``regen``
    inside the model (``absorb``, from ``fit``, their joint fit), every other coefficient
    refitted with the efficiency held (``rounds`` Gauss-Newton rounds: the clip moves with the
    force), ``n_eff ln(RSS(eff) / RSS_min)`` with ``n_eff = n / tau`` of ``fit``. Where it
    stays under a chi-square quantile (3.84: 95 %) is what the recording allows; a profile
    flat up to the bound of 1 says it cannot tell a plausible efficiency from a lossless
    one [-]."""
    inside = absorb(d, [*chosen, regen], fit).design
    at = inside.base.names.index("regen_efficiency")
    rss = []
    for eff in np.asarray(grid, float):
        lower, upper = inside.lower.copy(), inside.upper.copy()
        lower[at], upper[at] = eff - 1e-9, eff + 1e-9
        model = inside.base.with_theta({"regen_efficiency": float(eff)})
        for _ in range(rounds):
            held = replace(inside, base=model, lower=lower, upper=upper, cache={},
                           columns=inside.aligned(model.power_jacobian(inside.state)))
            fixed = fit_design(held, [])
            model = model.with_theta(dict(zip(model.names, fixed.theta)))
        rss.append(fixed.rmse_W ** 2)
    rss = np.asarray(rss)
    return d.n / fit.tau * np.log(rss / rss.min())
