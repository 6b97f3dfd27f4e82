"""Building the design: the recording's samples against the scenario's model, its
coefficients refitted, the grade's smoothing window chosen and the power's delay behind the
motion taken out (``build_design``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from orange_plan.errors import InputError
from orange_plan.identify.calibrate import autoregressive_inflation, recording_samples
from orange_plan.identify.diagnosis.candidates import TERM_CANDIDATES, candidates
from orange_plan.identify.diagnosis.design import (
    Design,
    _airborne,
    _baseline_model,
    _bounds,
)
from orange_plan.identify.diagnosis.fitting import _fit_rows, _linear_fit_at, noise_var_W2
from orange_plan.identify.diagnosis.settings import DEFAULT_SETTINGS, DiagnosisSettings


def build_design(recording, ctx, *, grade_window_m: float | None = None,
                 lag_s: float | None = None,
                 settings: DiagnosisSettings = DEFAULT_SETTINGS) -> Design:
    """The recording against the scenario's model (terms with all-zero coefficients left out),
    its coefficients refitted with physical bounds, the recorded power advanced by ``lag_s``
    (None: by the delay that best aligns it with the baseline, ``power_lag_s``), the grade
    taken over ``grade_window_m`` (None: the one of ``settings.grade_windows_m`` whose baseline
    predicts held-out blocks best: GPS heights need metres of smoothing, a survey-grade
    elevation map almost none, and a short steep ramp smoothed away reappears as a
    residual that other terms would be blamed for). ``settings``: the thresholds of every
    stage, carried by the design.

    Raises
    ------
    InputError
        Too few samples, or a recording without power.
    """
    if grade_window_m is not None or not recording.has("z_m"):
        return _design_at(recording, ctx, grade_window_m, lag_s, settings)
    designs = [_design_at(recording, ctx, w, lag_s, settings) for w in settings.grade_windows_m]
    return min(designs, key=_unconstrained_cv_rmse_W)


def _unconstrained_cv_rmse_W(d: Design) -> float:
    """The baseline's held-out RMSE with the prior's weight at unit noise, i.e. next to
    nothing against a recording's W^2 [W]: what a grade window is chosen by. The window is
    the elevation's measurement, which the data alone should tell; under the prior at its
    stated width, the window that best let the coefficients stay near the scenario's
    won instead (0.5 -> 5 m on a generated case, and the smoothed-away ramps were then
    blamed on a turning term)."""
    return _linear_fit_at(d, [], 1.0).cv_rmse_W


def _design_at(recording, ctx, grade_window_m, lag_s, settings: DiagnosisSettings) -> Design:
    """``build_design`` at one grade window."""
    samples = recording_samples([recording], ctx, settings.n_blocks, grade_window_m)
    n = samples.power_W.size
    if n < 50:
        raise InputError(f"{recording.source}: {n} samples are too few to diagnose (need >= 50)")
    model = _baseline_model(ctx)
    state = samples.state
    t = recording.t_s - recording.t_s[0]
    fold = samples.block[:, 1] % settings.n_folds
    lower, upper = _bounds(model.names)
    sd0 = np.sqrt(np.diag(model.cov)) * settings.prior_scale
    weight = np.where(sd0 > 0, 1.0 / np.where(sd0 > 0, sd0, 1.0) ** 2, 0.0)

    def refit(samples_now, column_delay=0.0, noise_var=1.0) -> Design:
        theta = np.clip(model.theta, lower, upper)
        design = Design(samples_now, model, np.zeros((n, len(model.names))), lower, upper,
                        model.theta.copy(), weight, fold, t,
                        _airborne(recording, settings.landed_min_s),
                        frozenset(recording.frame.columns), ctx.scenario, ctx.world,
                        recording.frame, column_delay=column_delay, settings=settings,
                        noise_var=noise_var)
        for _ in range(8):  # Gauss-Newton: the clip mask and the regen product settle
            design.base = model.with_theta(dict(zip(model.names, theta)))
            design.columns = design.aligned(design.base.power_jacobian(state))
            design.cache.clear()
            new = _fit_rows(design, design.columns, lower, upper, np.ones(n, bool))
            if np.allclose(new, theta, rtol=1e-6, atol=1e-9):
                break
            theta = new
        design.base = model.with_theta(dict(zip(model.names, theta)))
        design.columns = design.aligned(design.base.power_jacobian(state))
        design.cache.clear()
        return design

    def refit_at_its_noise(samples_now, column_delay=0.0) -> Design:
        """The baseline refitted with the prior weighed at unit noise, then again at the
        noise (variance times autocorrelation time) that fit leaves (``Design.noise_var``)."""
        loose = refit(samples_now, column_delay)
        return refit(samples_now, column_delay, _noise_var(loose))

    design = refit_at_its_noise(samples)
    if lag_s is None:
        lag_s = power_lag_s(design, recording.t_s, lag_columns(design))
    if lag_s:
        dt = float(np.median(np.diff(recording.t_s)))
        whole = float(np.floor(lag_s / dt + 1e-9))
        design = refit_at_its_noise(
            replace(samples, power_W=_advance(samples.power_W, recording.t_s, whole * dt)),
            column_delay=lag_s / dt - whole)
    design.lag_s = float(lag_s)
    design.grade_window_m = grade_window_m
    return design


def _noise_var(d: Design) -> float:
    """The noise the baseline's refit leaves: its residual at the refitted coefficients, whose
    mean square times autocorrelation time (``calibrate.autoregressive_inflation``) is
    ``fitting.noise_var_W2`` [W^2]."""
    resid = d.target - d.columns @ d.base.theta
    tau = autoregressive_inflation(resid, d.samples, d.settings.inflation_block_s)
    return noise_var_W2(float(np.mean(resid**2)), tau)


def power_lag_s(d: Design, t_s: np.ndarray, columns: np.ndarray) -> float:
    """Delay of the recorded power behind the motion, within ``settings.max_lag_s``
    (negative: it leads) [s]: the shift of the recorded power that a least-squares fit of
    ``columns`` explains best, refined between samples by a parabola through the best three.

    ``columns`` should hold every candidate's columns beside the baseline's
    (``lag_columns``): a term the baseline lacks but the power holds (an acceleration's
    inertia, a turn's torque) peaks at other moments than the baseline's power, and a
    delay fitted to the baseline alone slides the power towards those moments instead
    (a 0.45 s lag was read as a 0.17 s lead, and the inertia it hid went unseen)."""
    dt = float(np.median(np.diff(t_s)))
    most = int(min(round(d.settings.max_lag_s / dt), d.n // 10)) if dt > 0 else 0
    if most == 0:
        return 0.0
    inner = slice(most, d.n - most)
    x = np.asarray(columns, float)[inner]
    x = x / np.maximum(np.linalg.norm(x, axis=0), 1e-300)
    u, sv, _ = np.linalg.svd(x, full_matrices=False)
    basis = u[:, sv > sv[0] * 1e-8]  # the columns' span, rank deficiency dropped
    shifts = np.arange(-most, most + 1)
    ss = np.empty(shifts.size)
    for j, k in enumerate(shifts):
        y = _advance(d.y, t_s, k * dt)[inner]
        ss[j] = y @ y - np.sum((basis.T @ y) ** 2)
    i = int(np.argmin(ss))
    if 0 < i < ss.size - 1:
        curve = ss[i - 1] - 2 * ss[i] + ss[i + 1]
        step = 0.5 * (ss[i - 1] - ss[i + 1]) / curve if curve > 0 else 0.0
    else:
        step = 0.0
    return float((shifts[i] + step) * dt)


def lag_columns(d: Design) -> np.ndarray:
    """The baseline's columns and every applicable linear candidate's (the terms of
    ``TERM_CANDIDATES``), with a constant: what the delay is estimated against."""
    cols = [d.columns, np.ones((d.n, 1))]
    for cand in candidates():
        if cand.id in TERM_CANDIDATES and cand.applies(d) is None:
            cols.append(cand.effect(d, None, None).columns)
    return np.hstack(cols)


def _advance(values: np.ndarray, t_s: np.ndarray, lag_s: float) -> np.ndarray:
    """``values`` moved ``lag_s`` earlier (later when negative), linearly interpolated, the
    ends held."""
    if lag_s == 0:
        return values
    return np.interp(t_s + lag_s, t_s, values)
