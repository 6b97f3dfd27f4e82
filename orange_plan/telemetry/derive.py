"""Derivation on a recording's time series: its duration, gap-free pieces, centred moving averages,
central differences and the heading of positions (rule 13 of ``telemetry.recording``)."""

from __future__ import annotations

import itertools

import numpy as np

SMOOTH_WINDOW_S = 0.5
"""Centred moving-average window before differentiating positions or speed [s]."""
STILL_SPEED_MPS = 0.05
"""Below this horizontal speed the heading of positions is noise: it is held [m/s]."""


def duration_s(t_s) -> float:
    """A recording's duration: from its first to its last sample, gaps included [s]. The one
    definition every command reports (``simulate`` of what it wrote, ``predict`` of what it
    read), so the same file has the same duration in both."""
    t = np.asarray(t_s, float)
    return float(t[-1] - t[0]) if t.size else 0.0


def gap_free_pieces(t: np.ndarray, gap_threshold_s: float) -> list[slice]:
    """Gap-free runs of samples, as slices."""
    cuts = np.flatnonzero(np.diff(t) > gap_threshold_s) + 1
    bounds = [0, *cuts.tolist(), len(t)]
    return [slice(a, b) for a, b in itertools.pairwise(bounds)]


def window_samples(t: np.ndarray) -> int:
    """Samples in ``SMOOTH_WINDOW_S`` at the median interval: at least 3, odd."""
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    n = max(3, round(SMOOTH_WINDOW_S / dt)) if dt > 0 else 3
    return n + 1 - n % 2  # odd, so the average is centred


def smooth(values: np.ndarray, window: int) -> np.ndarray:
    """Centred moving average over ``window`` samples (odd).

    The ends are padded by point reflection (``2 v0 - v[k]``), so a steady trend (constant
    speed, constant slope) passes unchanged up to the first and last sample.
    """
    v = np.asarray(values, dtype=float)
    half = min(window // 2, len(v) - 1)
    if half <= 0:
        return v.copy()
    head = 2.0 * v[0] - v[half:0:-1]
    tail = 2.0 * v[-1] - v[-2:-half - 2:-1]
    padded = np.concatenate([head, v, tail])
    kernel = np.full(2 * half + 1, 1.0 / (2 * half + 1))
    return np.convolve(padded, kernel, mode="valid")


def derivative(values: np.ndarray, t: np.ndarray, pieces: list[slice]) -> np.ndarray:
    """Central differences per gap-free piece (one-sided at piece ends; 0 for 1 sample)."""
    out = np.zeros_like(values, dtype=float)
    for p in pieces:
        if p.stop - p.start >= 2:
            out[p] = np.gradient(values[p], t[p])
    return out


def smooth_pieces(values: np.ndarray, window: int, pieces: list[slice]) -> np.ndarray:
    out = np.array(values, dtype=float)
    for p in pieces:
        out[p] = smooth(values[p], window)
    return out


def position_noise_m(x_m, y_m, pieces=None) -> float:
    """Standard deviation of the white noise on recorded positions, estimated from the
    positions themselves [m].

    The second difference ``p[i+1] - 2 p[i] + p[i-1]`` of white noise of sd ``s`` has sd
    ``sqrt(6) s``, while a smooth track contributes only its acceleration times the sample
    interval squared (millimetres at a few hertz): so ``s`` is the second differences' robust
    spread (1.4826 x their median absolute deviation, which turns and stops do not move)
    over ``sqrt(6)``, pooled over x, y and the gap-free ``pieces``. 0 for fewer than three
    samples in every piece.
    """
    x, y = np.asarray(x_m, float), np.asarray(y_m, float)
    pieces = pieces or [slice(0, len(x))]
    second = [np.diff(v[p], 2) for p in pieces for v in (x, y) if len(v[p]) >= 3]
    if not second:
        return 0.0
    dd = np.concatenate(second)
    dd = dd[np.isfinite(dd)]
    if not dd.size:
        return 0.0
    return float(1.4826 * np.median(np.abs(dd - np.median(dd))) / np.sqrt(6.0))


def position_heading_rad(x_m, y_m, t_s, pieces=None, speed_mps=None,
                         still_mps: float = STILL_SPEED_MPS, window: int | None = None
                         ) -> np.ndarray:
    """Unwrapped heading of smoothed positions [rad], held where the robot does not move
    sideways.

    The heading is held where the horizontal speed of the smoothed positions is at most
    ``still_mps`` [m/s], and where the recorded ``speed_mps`` (when given) is: a vehicle that
    climbs or descends on the spot has a fast 3-D speed but no heading of its own, and the
    direction of its few centimetres of drift would turn at hundreds of rad/s. ``window``:
    samples of the centred moving average (default ``window_samples``; 1: none, for positions
    already smooth).
    """
    t = np.asarray(t_s, float)
    pieces = pieces or [slice(0, len(t))]
    w = window_samples(t) if window is None else window
    xs = smooth_pieces(np.asarray(x_m, float), w, pieces)
    ys = smooth_pieces(np.asarray(y_m, float), w, pieces)
    vx, vy = derivative(xs, t, pieces), derivative(ys, t, pieces)
    moving = np.hypot(vx, vy) > still_mps
    if speed_mps is not None:
        moving &= np.asarray(speed_mps, float) > still_mps
    return np.unwrap(held_where_valid(np.arctan2(vy, vx), moving))


def position_yaw_rate_radps(x_m, y_m, t_s, pieces=None, speed_mps=None,
                            still_mps: float = STILL_SPEED_MPS,
                            window: int | None = None) -> np.ndarray:
    """Yaw rate of positions: central differences of ``position_heading_rad`` per gap-free
    piece [rad/s] (zero where the heading is held)."""
    t = np.asarray(t_s, float)
    pieces = pieces or [slice(0, len(t))]
    heading = position_heading_rad(x_m, y_m, t, pieces, speed_mps, still_mps, window)
    return derivative(heading, t, pieces)


def held_where_valid(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``values`` where ``valid``, elsewhere the last valid one before (the first valid one
    before any; 0 when none is valid)."""
    if not valid.any():
        return np.zeros(values.shape)
    index = np.where(valid, np.arange(values.size), 0)
    np.maximum.accumulate(index, out=index)
    index[: int(np.argmax(valid))] = int(np.argmax(valid))
    return values[index]
