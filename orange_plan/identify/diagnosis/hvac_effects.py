"""An HVAC that follows the ambient temperature as a candidate's effect
(``_hvac_ambient_effect``): its heating and cooling set-points scanned in pairs, each pair's
columns judged by their parts orthogonal to the baseline's columns (``_hvac_scan``).
"""

from __future__ import annotations

import numpy as np

from orange_plan.identify.calibrate import autoregressive_inflation
from orange_plan.identify.diagnosis.design import Design, Effect, _bounds
from orange_plan.identify.diagnosis.effects import _column_basis, _term_columns, _term_effect
from orange_plan.identify.diagnosis.fitting import _fit_rows
from orange_plan.physics.state import MotionState
from orange_plan.physics.terms import (
    HVAC_SETPOINT_C,
    HVAC_SETPOINT_RANGE_C,
    hvac_ambient_feature,
    hvac_ambient_term,
)


def _hvac_ambient_effect(d: Design, resid, rows) -> Effect:
    """Heating below one set-point and cooling above another, following the ambient
    temperature (``physics.terms.hvac_ambient_term``), the set-points those that leave the
    least of the training rows' residual: every pair ``heat <= cool`` on a grid of
    ``settings.hvac_setpoint_step_K`` over HVAC_SETPOINT_RANGE_C, each pair's two columns
    judged by their parts orthogonal to the baseline's columns (``_hvac_scan``), with both
    coefficients kept at or above 0 (a climate control that only heats, or only cools, is a
    pair with one coefficient at 0), and a set-point moved off 20 C only where the
    information criterion says the fit earns it (``_hvac_choice``). A climate control with
    a dead band (heating below 18 C, cooling above 24 C), fitted at one 20 C set-point, came
    out with its heating 21-30 % and its cooling 49-59 % low.

    Set-points the recording cannot tell apart (the ambient never reached them: every
    heating set-point above the warmest ambient fits alike) are a tie, and the tie's member
    nearest the vocabulary's 20 C is kept. A side that runs has its set-point's standard
    error from the joint covariance (``_hvac_joint_sd``); a side whose coefficient is 0, half
    the span of set-points whose pair fits within one unit of chi-square (the variance left
    after the chosen pair x the autocorrelation time) of the best, so an unseen one says how
    little is known of it. Without a residual (the power's delay estimate): the
    vocabulary's set-point."""
    if resid is None:
        return _term_effect("hvac_ambient")(d, resid, rows)
    lo, hi = HVAC_SETPOINT_RANGE_C
    grid = np.arange(lo, hi + 1e-9, d.settings.hvac_setpoint_step_K)
    fall = _hvac_scan(d, resid, rows, grid)
    tau = _hvac_autocorrelation(d, resid, rows, grid, fall)
    rr = float(resid[rows] @ resid[rows])
    i, j = _hvac_choice(fall, grid, rr, rows.sum() / tau)
    best = float(fall[i, j])
    # one unit of chi-square: the noise left once the chosen pair is fitted, not the
    # residual it is fitted to (which still holds the heating and cooling)
    noise = max(rr - best, 0.0) / max(int(rows.sum()), 1) * tau
    near = fall >= best - noise
    least_sd = 0.5 * d.settings.hvac_setpoint_step_K
    band_sd = [max(0.5 * float(np.ptp(grid[np.any(near, axis=1)])), least_sd),
               max(0.5 * float(np.ptp(grid[np.any(near, axis=0)])), least_sd)]
    heat, cool = float(grid[i]), float(grid[j])
    eff = _term_columns(d, "hvac_ambient", hvac_ambient_term(heat, cool))
    sd, scale = _hvac_joint_sd(d, resid, rows, eff.columns, (heat, cool), noise)
    # a side whose coefficient is 0 has no slope to date its set-point: the band's span
    sd = [band if s is None else max(s, least_sd) for s, band in zip(sd, band_sd)]
    return Effect(eff.columns, eff.names, eff.lower, eff.upper,
                  {"hvac_heat_below_C": (heat, sd[0]), "hvac_cool_above_C": (cool, sd[1])},
                  sd_scale=scale, scanned=int(np.sum(_moved(np.array([heat, cool])))))


def _hvac_autocorrelation(d: Design, resid, rows, grid, fall) -> float:
    """The autocorrelation time [samples] of what is left once the best-fitting pair of
    set-points is fitted: the residual handed in still holds the heating and cooling, whose
    slow swings made its autocorrelation time several times the noise's, and the
    information criterion's effective sample count then too small to prefer any set-point
    (a dead band at 16.7 / 20.8 C stayed at 20 C, its heating 15 % low)."""
    i, j = np.unravel_index(np.argmax(fall), fall.shape)
    temp = d.frame["ambient_C"].to_numpy(float)
    state = MotionState(speed_mps=np.ones(d.n), channels={"ambient_C": temp})
    heating, cooling = hvac_ambient_feature(float(grid[i]), float(grid[j]))(state)
    scale = _battery_side_scale(d)
    x = np.column_stack([d.columns, scale * heating, scale * cooling])
    beta = np.linalg.lstsq(x[rows], resid[rows] + d.columns[rows] @ d.base.theta, rcond=None)[0]
    left = resid + d.columns @ d.base.theta - x @ beta
    return autoregressive_inflation(left, d.samples, d.settings.inflation_block_s)


def _moved(setpoints: np.ndarray) -> np.ndarray:
    """Which set-points are moved off the vocabulary's HVAC_SETPOINT_C: the parameters an
    HVAC's scan chose, which the information criterion charges."""
    return setpoints != HVAC_SETPOINT_C


def _hvac_choice(fall, grid, rr: float, n_eff: float) -> tuple[int, int]:
    """The pair of set-points with the least BIC, ``n_eff ln(RSS) + k ln(n_eff)`` with ``k``
    the set-points moved off HVAC_SETPOINT_C, the tie's member nearest it: a set-point is
    moved only where the fit earns it. On a trip that stays on one side of 20 C, the pair
    that fitted the training rows best put a kink inside the trip's few kelvin, and held out
    its extrapolation lost 2,566 % where the one set-point gained."""
    moved = np.add.outer(_moved(grid), _moved(grid)).astype(float)
    rss = np.maximum(rr - fall, 1e-300)
    n_eff = max(float(n_eff), 2.0)
    bic = np.where(np.isfinite(fall), n_eff * np.log(rss) + moved * np.log(n_eff), np.inf)
    least = float(bic.min())
    tie = bic <= least + 1e-9 * max(abs(least), 1.0)
    distance = np.add.outer(np.abs(grid - HVAC_SETPOINT_C), np.abs(grid - HVAC_SETPOINT_C))
    i, j = np.unravel_index(np.argmin(np.where(tie, distance, np.inf)), fall.shape)
    return int(i), int(j)


def _hvac_joint_sd(d: Design, resid, rows, columns, setpoints, noise: float):
    """The set-points' standard errors and the factor by which each coefficient's grows,
    from the joint covariance of the baseline's coefficients, the two HVAC coefficients and
    the set-points (their Jacobian columns: ``a s`` where the heating runs, ``-b s`` where
    the cooling runs, as in a segmented regression), ``noise`` the residual variance times
    its autocorrelation time. Fitted at set-points held fixed, a dead band's cooling came
    out 3.3 standard errors from the truth while its set-point was 0.15 K off. A set-point
    whose coefficient is 0 gets None."""
    p = d.columns.shape[1]
    lower, upper = _bounds(("hvac_heat_W_per_K", "hvac_cool_W_per_K"))
    theta = _fit_rows(d, np.hstack([d.columns, columns]), np.r_[d.lower, lower],
                      np.r_[d.upper, upper], rows)  # the fit the candidate is judged by
    a, b = theta[-2:]
    x = np.hstack([d.columns[rows], columns[rows]])
    temp = d.frame["ambient_C"].to_numpy(float)[rows]
    scale = _battery_side_scale(d)[rows]
    heat, cool = setpoints
    slopes = [(a, a * scale * (temp < heat)), (b, -b * scale * (temp > cool))]
    active = [k for k, (coef, col) in enumerate(slopes) if coef > 0 and np.any(col)]
    derivatives = [slopes[k][1] for k in active]
    if len(active) == 2 and heat == cool:
        # one set-point for both: beside the constant load its two columns are one
        derivatives = [derivatives[0] + derivatives[1]]
    joint = np.hstack([x, np.column_stack(derivatives)]) if derivatives else x
    cov = np.linalg.pinv(joint.T @ joint) * noise
    fixed = np.linalg.pinv(x.T @ x) * noise
    ratio = np.sqrt(np.clip(np.diag(cov)[p:p + 2], 0.0, None)
                    / np.maximum(np.diag(fixed)[p:p + 2], 1e-300))
    sd: list = [None, None]
    for n, k in enumerate(active):
        at = p + 2 + min(n, len(derivatives) - 1)  # a shared set-point: its one column
        sd[k] = float(np.sqrt(max(cov[at, at], 0.0)))
    return sd, np.maximum(ratio, 1.0)


def _battery_side_scale(d: Design) -> np.ndarray:
    """Per sample, what a battery-side power of 1 W costs the battery: ``1 + 2 B P`` with the
    in-battery loss, which the baseline's constant load (``ancillary_W``) column carries (1
    without one) [-]."""
    if "ancillary_W" not in d.base.names:
        return np.ones(d.n)
    return d.columns[:, d.base.names.index("ancillary_W")]


def _hvac_scan(d: Design, resid, rows, grid) -> np.ndarray:
    """The fall of the training rows' residual sum of squares for each pair of set-points
    (heating below grid[i], cooling above grid[j]); -inf where i > j.

    A heating column ``s (T_h - T)`` on the samples colder than ``T_h`` (``s`` the
    battery side's scale, ``_battery_side_scale``) has every inner product the fit needs (with itself, the
    residual and the baseline's orthonormal basis Q) as a polynomial in ``T_h`` over the
    samples sorted by temperature: cumulative sums give all set-points at once, as a
    payload's change times are scanned. Cooling is the same over the warmer samples; the two
    never overlap when ``T_h <= T_c``, so their product is what Q shares of both. The scan
    leaves out the fraction of a sample the model's columns are delayed by (the ambient
    changes over minutes); the chosen pair's columns have it."""
    temp = d.frame["ambient_C"].to_numpy(float)[rows]
    scale = _battery_side_scale(d)[rows]
    q = _column_basis(d.columns[rows])
    order = np.argsort(temp, kind="stable")
    t, s, r, q = temp[order], scale[order], resid[rows][order], q[order]
    # per sample: the pieces whose sums over a range of temperatures give each inner product
    # as a polynomial in the set-point
    pieces = np.column_stack([s * s, s * s * t, s * s * t * t, r * s, r * s * t,
                              q * s[:, None], q * (s * t)[:, None]])
    prefix = np.vstack([np.zeros(pieces.shape[1]), np.cumsum(pieces, axis=0)])
    colder = prefix[np.searchsorted(t, grid, side="left")]  # sums over T < set-point
    warmer = prefix[-1] - prefix[np.searchsorted(t, grid, side="right")]  # over T > it
    k = q.shape[1]
    rq = r @ q

    def products(sums, sign):
        """(own c.c, r.own, Q'c) of the columns ``sign (set-point - T)`` over ``sums``'
        samples, ``own`` the part orthogonal to Q."""
        cc = grid**2 * sums[:, 0] - 2 * grid * sums[:, 1] + sums[:, 2]
        rc = sign * (grid * sums[:, 3] - sums[:, 4])
        qc = sign * (grid[:, None] * sums[:, 5:5 + k] - sums[:, 5 + k:5 + 2 * k])
        own_cc = np.maximum(cc - np.einsum("ij,ij->i", qc, qc), 0.0)
        return own_cc, rc - qc @ rq, qc

    hh, rh, qh = products(colder, 1.0)
    cc, rc, qc = products(warmer, -1.0)
    fall = _two_column_fall(rh, rc, hh, cc, -(qh @ qc.T))
    fall[np.subtract.outer(grid, grid) > 0] = -np.inf  # heat <= cool
    return fall


def _two_column_fall(rh, rc, hh, cc, hc) -> np.ndarray:
    """The fall of the residual sum of squares of the best non-negative fit ``a h + b c`` for
    every pair (heat column i, cool column j), from the inner products: the unconstrained
    pair where both coefficients come out >= 0, else the better of the single columns with a
    positive coefficient, else 0 (neither helps)."""
    heat_only = np.where((rh > 0) & (hh > 0), rh**2 / np.where(hh > 0, hh, 1.0), 0.0)
    cool_only = np.where((rc > 0) & (cc > 0), rc**2 / np.where(cc > 0, cc, 1.0), 0.0)
    single = np.maximum(heat_only[:, None], cool_only[None, :])
    det = np.outer(hh, cc) - hc**2
    ok = det > 1e-9 * np.maximum(np.outer(hh, cc), 1e-300)
    safe = np.where(ok, det, 1.0)
    a = (rh[:, None] * cc[None, :] - rc[None, :] * hc) / safe
    b = (rc[None, :] * hh[:, None] - rh[:, None] * hc) / safe
    both = ok & (a >= 0) & (b >= 0)
    pair = np.where(both, a * rh[:, None] + b * rc[None, :], 0.0)
    return np.maximum(pair, single)
