"""Helpers shared by the importers: putting channels sampled at other times on one grid."""

from __future__ import annotations

import numpy as np

from orange_plan.errors import RecordingError


def onto_times(base_t_s, t_s, values, max_gap_s: float) -> np.ndarray:
    """Linear interpolation of ``values`` (sampled at ``t_s``) onto ``base_t_s``.

    A base time farther than ``max_gap_s`` from every source sample gets NaN (never
    extrapolated or bridged over a long silence), so the recording checks report and drop
    it instead of inventing data.

    Parameters
    ----------
    base_t_s : target times [s]
    t_s : source times, any order [s]
    values : source values, one per source time
    max_gap_s : largest accepted distance to the nearest source sample [s]
    """
    base = np.asarray(base_t_s, dtype=float)
    t = np.asarray(t_s, dtype=float)
    v = np.asarray(values, dtype=float)
    if t.size == 0:
        return np.full(base.shape, np.nan)
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    out = np.interp(base, t, v, left=np.nan, right=np.nan)
    k = np.searchsorted(t, base)
    before = t[np.clip(k - 1, 0, t.size - 1)]
    after = t[np.clip(k, 0, t.size - 1)]
    nearest = np.minimum(np.abs(base - before), np.abs(after - base))
    out[nearest > max_gap_s] = np.nan
    # interp gives NaN outside [t0, t_end]; accept samples within max_gap_s of an end
    near_ends = np.isnan(out) & (nearest <= max_gap_s)
    out[near_ends] = np.interp(base[near_ends], t, v)
    return out


def need_rows(frame, what: str, source) -> None:
    """Refuse an import that found no samples of ``what``."""
    if len(frame) == 0:
        raise RecordingError(f"{source}: no {what} samples found")
