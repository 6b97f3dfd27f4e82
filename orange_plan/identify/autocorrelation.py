"""The integrated autocorrelation time of fit residuals: what turns a residual variance into
the noise variance of autocorrelated samples (calibration's and diagnosis's standard errors).

Power residuals are autocorrelated (a controller, a gust, a slope lasts seconds), so ``n``
samples carry the information of about ``n / tau`` independent ones, ``tau`` the integrated
autocorrelation time in samples. Two estimates: batch means (``inflation_factor``) and an
autoregression of one-second means (``autoregressive_inflation``), which falls back to batch
means on runs too short for it. ``samples`` is a ``calibrate.Samples``: its ``dt_s`` and the
recording index of each sample (``block[:, 0]``) are read.
"""

from __future__ import annotations

import numpy as np


def inflation_factor(resid: np.ndarray, samples, block_s: float) -> float:
    """Integrated autocorrelation time of residuals in samples, by batch means (>= 1) [-].

    ``tau = B var(mean of each batch of B samples) / var(residuals)``, batches of about
    ``block_s`` seconds within each recording; 1 for white residuals.
    """
    var = float(np.var(resid))
    dt = samples.dt_s[samples.dt_s > 0]
    if var <= 0 or dt.size == 0:
        return 1.0
    b = int(max(1, min(round(block_s / float(np.median(dt))), resid.size // 20)))
    if b <= 1:
        return 1.0
    batches = _batch_means(resid, samples, b)
    means = np.concatenate(batches) if batches else np.zeros(0)
    if means.size < 5:
        return 1.0
    return max(1.0, b * float(np.var(means)) / var)


AR_BIN_S = 1.0
"""Bin of the means an autoregressive inflation is fitted to [s]: sensor noise and lag
live within a second, disturbances (gusts, a controller, traffic) over tens of seconds."""
AR_MAX_ORDER = 20
"""Largest order of that autoregression [bins]."""
AR_MIN_BINS = 300
"""Fewest bins for an autoregressive inflation; shorter runs use batch means [-]."""
AR_MIN_DISTANCE_TO_UNIT_ROOT = 1e-3
"""``1 - sum(phi)`` is held at least this far from 0: a residual that wanders like a random
walk has an unbounded long-run variance, and a huge finite one says the same [-]."""


def autoregressive_inflation(resid: np.ndarray, samples,
                             fallback_block_s: float) -> float:
    """Integrated autocorrelation time of residuals in samples, from an autoregression of
    their 1 s means (>= 1) [-].

    ``tau = m S(0) / var(residuals)``: ``m`` samples per bin, ``S(0) = s_e^2 / (1 -
    sum(phi))^2`` the long-run variance of the bin means under their AR(p) model (Yule-Walker
    on autocovariances pooled over the recordings, p <= ``AR_MAX_ORDER`` by BIC). Batch means
    (``inflation_factor``) rest on about twenty batch means of a 30-minute run; after a fit
    that picked a change time to remove the run's slowest wander, one of them goes with it
    and the estimate falls by up to two thirds. The autoregression reads the same long-run
    variance from every lag of 1800 bins. Runs with fewer than ``AR_MIN_BINS`` bins fall back
    to batch means of ``fallback_block_s``.
    """
    from scipy.linalg import solve_toeplitz

    var = float(np.var(resid))
    dt = samples.dt_s[samples.dt_s > 0]
    if var <= 0 or dt.size == 0:
        return 1.0
    m = int(max(1, round(AR_BIN_S / float(np.median(dt)))))
    series = _batch_means(resid, samples, m)
    n = sum(s.size for s in series)
    if n < AR_MIN_BINS:
        return inflation_factor(resid, samples, fallback_block_s)
    mean = float(np.mean(np.concatenate(series)))
    centred = [s - mean for s in series]
    acov = np.array([sum(float(c[: c.size - j] @ c[j:]) for c in centred if c.size > j) / n
                     for j in range(AR_MAX_ORDER + 1)])
    if acov[0] <= 0:
        return 1.0
    best = (np.log(acov[0]) * n, acov[0], 0.0)  # (BIC, innovation variance, sum of phi)
    for p in range(1, AR_MAX_ORDER + 1):
        phi = solve_toeplitz(acov[:p], acov[1: p + 1])
        s2 = float(acov[0] - phi @ acov[1: p + 1])
        if s2 <= 0:
            break
        bic = n * np.log(s2) + p * np.log(n)
        if bic < best[0]:
            best = (bic, s2, float(np.sum(phi)))
    _, s2, phi_sum = best
    long_run = s2 / max(1.0 - phi_sum, AR_MIN_DISTANCE_TO_UNIT_ROOT) ** 2
    return max(1.0, m * long_run / var)


def _batch_means(resid: np.ndarray, samples, b: int) -> list[np.ndarray]:
    """Means of consecutive batches of ``b`` samples within each recording."""
    out = []
    for rec in np.unique(samples.block[:, 0]):
        r = resid[samples.block[:, 0] == rec]
        k = r.size // b
        if k:
            out.append(r[: k * b].reshape(k, b).mean(axis=1))
    return out
