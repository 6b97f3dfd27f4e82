"""Locating where a recording and a model disagree: in time, in operating conditions, in space.

``identify.diagnosis`` hands in its design (the recording against the refitted baseline) and
the baseline's residual (recorded minus predicted battery power); this module says where the
residual departs from zero, in words a person can check against the recording. ``d`` in the
functions below is that design (``identify.diagnosis.design.Design``: samples, state, time,
frame, world, recorded power); it is not imported here, which would import diagnosis back.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Mismatch:
    """A time window where the baseline's residual departs from zero (docs/guide/diagnosis.md).

    Attributes
    ----------
    t_start_s, t_end_s : the window [s]
    mean_residual_W : mean recorded minus predicted power in it [W]
    where : plain-language condition that sets the window apart
    """

    t_start_s: float
    t_end_s: float
    mean_residual_W: float
    where: str


def locate(d, resid: np.ndarray, max_windows: int = 8) -> list[Mismatch]:
    """Windows of significant residual: change points of the residual's 1 s means
    (``ruptures`` PELT on the least-squares cost, penalty ``4 s2 tau log n``), kept where
    the window's mean is more than 3 standard errors from zero and above 2 % of the mean
    power. ``s2`` and ``tau`` describe the noise *around* the windows, so they are taken
    from what a running median leaves (a step must not inflate its own yardstick)."""
    import ruptures
    from scipy.ndimage import median_filter

    edges, means, _counts = per_second(d.t_s, resid)
    if means.size < 20:
        return []
    wiggle = means - median_filter(means, size=31, mode="nearest")
    s2 = float(np.var(wiggle))
    if s2 <= 0:
        return []
    rho = float(np.clip(np.corrcoef(wiggle[:-1], wiggle[1:])[0, 1], 0.0, 0.95))
    tau = (1 + rho) / (1 - rho)
    pen = 4.0 * s2 * tau * np.log(means.size)
    # KernelCPD with a linear kernel is PELT on the least-squares cost, compiled (the pure
    # Python Pelt took 8 s on a 25-minute run)
    breaks = ruptures.KernelCPD(kernel="linear", min_size=10).fit(means[:, None]).predict(pen=pen)
    out = []
    lo = 0
    for hi in breaks:
        seg = means[lo:hi]
        se = np.sqrt(s2 * tau / seg.size)
        if abs(seg.mean()) > 3.0 * se and abs(seg.mean()) > 0.02 * d.mean_power_W:
            t0, t1 = float(edges[lo]), float(edges[hi])
            inside = (d.t_s >= t0) & (d.t_s < t1)
            out.append(Mismatch(t0, t1, float(np.mean(resid[inside])), describe(d, inside)))
        lo = hi
    out.sort(key=lambda m: -abs(m.mean_residual_W) * (m.t_end_s - m.t_start_s))
    return sorted(out[:max_windows], key=lambda m: m.t_start_s)


def locate_by_condition(d, resid: np.ndarray, conditions: list[dict],
                        most: int = 3) -> list[Mismatch]:
    """Mismatches tied to an operating condition rather than a time window (a turn, a hill,
    a cold battery recur through the run): for each significant condition (strongest rank
    correlation first), the samples in its quartile with the largest mean residual, reported
    over the span they occur in."""
    out = []
    values = condition_values(d)
    flagged = sorted((c for c in conditions if c["significant"] and c["condition"] != "time"),
                     key=lambda c: -abs(c["spearman_rho"]))
    for cond in flagged[:most]:
        arr = values[cond["condition"]]
        upper, lower = quarters(arr)
        if not (upper.any() and lower.any()):
            continue
        pick_upper = abs(np.mean(resid[upper])) >= abs(np.mean(resid[lower]))
        hit = upper if pick_upper else lower
        bound = arr[upper].min() if pick_upper else arr[lower].max()
        t = d.t_s[hit]
        where = condition_phrase(cond["condition"], pick_upper, bound)
        out.append(Mismatch(float(t[0]), float(t[-1]), float(np.mean(resid[hit])), where))
    return out


def condition_phrase(name: str, higher: bool, bound: float) -> str:
    """"while X >= bound" (or "<="): inclusive, since ``bound`` is a value the samples take
    (a payload of exactly 0 kg is "<= 0 kg", never "< 0 kg"). Every mismatch row is worded
    here, so one condition found two ways reads the same and ``merge_equal_conditions``
    can see it."""
    _values, label, unit = CONDITIONS[name]
    return f"while {label} {'>=' if higher else '<='} {bound:.3g}{' ' + unit if unit else ''}"


def merge_equal_conditions(windows: list[Mismatch], by_condition: list[Mismatch]
                           ) -> list[Mismatch]:
    """The time windows, then each condition's row unless a window already states the same
    condition over an overlapping span (the same finding, reached twice: one row)."""
    out = list(windows)
    for m in by_condition:
        if not any(w.where == m.where and w.t_start_s <= m.t_end_s and m.t_start_s <= w.t_end_s
                   for w in out):
            out.append(m)
    return out


def quarters(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Samples in the top and bottom quarter of ``values``. When most samples share one
    value (a yaw rate of 0 on straight runs) that value is one side and the rest the other,
    so neither side is empty while the values differ."""
    lo_q, hi_q = np.percentile(values, [25, 75])
    if lo_q < hi_q:
        return values >= hi_q, values <= lo_q
    if np.any(values > hi_q):
        return values > hi_q, values <= lo_q
    return values >= hi_q, values < lo_q


def per_second(t_s: np.ndarray, values: np.ndarray):
    """Means of ``values`` over whole seconds: (second edges, means, samples per second)."""
    sec = np.floor(t_s).astype(int)
    sec -= sec[0]
    counts = np.bincount(sec)
    sums = np.bincount(sec, values)
    keep = counts > 0
    edges = np.r_[np.flatnonzero(keep), np.flatnonzero(keep)[-1] + 1].astype(float) + t_s[0] * 0
    return edges, sums[keep] / counts[keep], counts[keep]


CONDITIONS: dict[str, tuple[Callable, str, str]] = {
    # name -> (values of the design, label in a sentence, unit)
    "speed": (lambda d: d.state.speed_mps, "speed", "m/s"),
    "acceleration": (lambda d: np.abs(d.state.accel_mps2), "|acceleration|", "m/s^2"),
    "grade": (lambda d: d.state.sin_t, "grade", ""),
    "yaw_rate": (lambda d: np.abs(d.state.yaw_rate_radps), "|yaw rate|", "rad/s"),
    "heading": (lambda d: np.degrees(np.arctan2(d.state.dir_x, d.state.dir_y)) % 360.0,
                "heading", "deg"),
    "ambient_C": (lambda d: d.frame["ambient_C"].to_numpy(float), "ambient temperature", "C"),
    "battery_C": (lambda d: d.frame["battery_C"].to_numpy(float), "battery temperature", "C"),
    "payload_kg": (lambda d: d.frame["payload_kg"].to_numpy(float), "payload", "kg"),
    "sensor_rate_Hz": (lambda d: d.frame["sensor_rate_Hz"].to_numpy(float), "sensor rate", "Hz"),
    "time": (lambda d: d.t_s, "time since start", "s"),
}
"""Operating conditions the residual is examined against (the recording's optional columns when present; docs/formats.md)."""


def condition_values(d) -> dict[str, np.ndarray]:
    out = {}
    for name, (values, _label, _unit) in CONDITIONS.items():
        if name in ("ambient_C", "battery_C", "payload_kg", "sensor_rate_Hz") and \
                name not in d.columns_of:
            continue
        arr = np.broadcast_to(np.asarray(values(d), float), (d.n,))
        if np.all(np.isfinite(arr)) and np.ptp(arr) > 0:
            out[name] = arr
    return out


def describe(d, inside: np.ndarray) -> str:
    """The condition that best sets ``inside`` apart: a surface it is on, or a feature
    whose values differ most (standardised mean difference), as "while X >= q" (q: the
    quartile of the window's values on the far side: three quarters of them pass)."""
    surface = _surface_phrase(d, inside)
    best, best_score = None, 0.5
    for name, arr in condition_values(d).items():
        if name == "time" or inside.all() or not inside.any():
            continue
        sd = float(np.std(arr))
        score = abs(arr[inside].mean() - arr[~inside].mean()) / sd if sd > 0 else 0.0
        if score > best_score:
            best, best_score = name, score
    parts = []
    if best is not None:
        arr = condition_values(d)[best]
        higher = arr[inside].mean() > arr[~inside].mean()
        q = np.percentile(arr[inside], 25 if higher else 75)
        parts.append(condition_phrase(best, higher, q))
    if surface:
        parts.append(surface)
    if not parts:
        t = d.t_s[inside]
        return (f"from t = {t[0]:.0f} s to {t[-1]:.0f} s, no operating condition stands apart "
                "(a change in time)")
    return ", ".join(parts)


def _surface_phrase(d, inside: np.ndarray) -> str:
    code = np.broadcast_to(np.asarray(d.state.surface_code), (d.n,))
    names = d.world.map.surface_names
    for i, name in enumerate(names):
        share_in = np.mean(code[inside] == i) if inside.any() else 0.0
        share_out = np.mean(code[~inside] == i) if (~inside).any() else 0.0
        if share_in > 0.6 and share_in > 2 * share_out:
            return f"on the map's '{name}' surface"
    return ""


def residual_by_condition(d, resid: np.ndarray, tau: float) -> list[dict]:
    """Residual against each operating condition: rank correlation and the mean residual in
    the condition's quartiles; flagged when |rho| exceeds 4 standard errors under
    autocorrelation (``sqrt(tau / n)``)."""
    from scipy.stats import spearmanr

    out = []
    for name, arr in condition_values(d).items():
        rho = float(spearmanr(arr, resid).statistic)
        edges = np.unique(np.percentile(arr, [0, 25, 50, 75, 100]))
        which = np.clip(np.searchsorted(edges, arr, side="right") - 1, 0, max(0, edges.size - 2))
        means = [float(np.mean(resid[which == k])) for k in range(max(1, edges.size - 1))
                 if np.any(which == k)]
        out.append({"condition": name, "spearman_rho": rho,
                    "significant": bool(abs(rho) > 4.0 * np.sqrt(tau / d.n)),
                    "quartile_mean_residual_W": means})
    return out


def residual_by_surface(d, resid: np.ndarray) -> list[dict]:
    """Mean residual on each map surface seen and on default ground (space)."""
    code = np.broadcast_to(np.asarray(d.state.surface_code), (d.n,))
    names = [*d.world.map.surface_names]
    out = []
    for i in np.unique(code):
        hit = code == i
        label = names[i] if i >= 0 else (getattr(d.world, "default_surface_name", None)
                                         or "default ground")
        out.append({"surface": label, "share": float(hit.mean()),
                    "mean_residual_W": float(np.mean(resid[hit]))})
    return out
