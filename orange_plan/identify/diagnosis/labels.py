"""Per-surface rolling read from a recording's ``surface`` labels (a terrain classifier's),
where the map has no surfaces: the labels as codes, their delay and majority window, the
candidate's columns, and the design with the labels as its map's surfaces.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from orange_plan.identify.calibrate import autoregressive_inflation
from orange_plan.identify.diagnosis.design import Design, Effect


@dataclass(frozen=True)
class SurfaceLabels:
    """A recording's ``surface`` labels as codes.

    Attributes
    ----------
    code : per sample, the index of its label in ``own``, -1 for a label with no coefficient
        of its own (the reference, or one seen too little)
    own : the labels that get a rolling coefficient of their own
    reference : the label the baseline's one rolling coefficient stands for
    """

    code: np.ndarray
    own: list[str]
    reference: str


@dataclass(frozen=True)
class LabelLag:
    """The labels' delay behind the ground under the wheels and their majority window.

    Attributes
    ----------
    samples : the delay in whole samples
    window_samples : the majority window in samples (<= 1: the labels as given)
    lag_s : the delay [s]
    sd_s : its standard error [s]
    """

    samples: int
    window_samples: int
    lag_s: float
    sd_s: float


def surface_labels(d: Design) -> SurfaceLabels:
    """The recording's ``surface`` labels as codes (``SurfaceLabels``).

    The reference is the map's default surface when the labels use its name, else the label
    most driven on: the baseline's one rolling coefficient stands for it, and every other
    label seen on at least ``settings.min_label_share`` of the moving samples gets its change
    from it (all of them would repeat the baseline's column)."""
    if "surface_labels" not in d.cache:
        raw = d.frame["surface"].astype(str).str.strip().str.lower().to_numpy()
        moving = np.asarray(d.state.speed_mps) > 0
        names, counts = np.unique(raw[moving], return_counts=True)
        known = [(c, n) for n, c in zip(names, counts)
                 if n not in ("", "nan", "none")
                 and c >= d.settings.min_label_share * max(1, moving.sum())]
        default = str(d.world.default_surface_name).lower()
        ranked = [n for _, n in sorted(known, reverse=True)]
        reference = default if default in ranked else (ranked[0] if ranked else "")
        own = sorted(n for n in ranked if n != reference)
        code = np.full(d.n, -1)
        for i, name in enumerate(own):
            code[raw == name] = i
        d.cache["surface_labels"] = SurfaceLabels(code, own, reference)
    return d.cache["surface_labels"]


def _label_columns(d: Design, lag_samples: int, window_samples: int = 0) -> np.ndarray:
    """Rolling column on each own label's samples, the labels (their majority over
    ``window_samples``, ``_majority``) read ``lag_samples`` later (a label at t describes the
    ground at t - lag; the last label held) [W per kg]."""
    labels = surface_labels(d)
    code, own = labels.code, labels.own
    if window_samples > 1:
        key = ("label_majority", window_samples)
        if key not in d.cache:
            d.cache[key] = _majority(code, len(own), window_samples)
        code = d.cache[key]
    rolling = d.rolling_column
    later = code[np.minimum(np.arange(d.n) + lag_samples, d.n - 1)]
    return np.stack([rolling * (later == i) for i in range(len(own))], axis=1)


def _majority(code: np.ndarray, n_codes: int, window: int) -> np.ndarray:
    """The most frequent of codes -1 .. n_codes - 1 in a centred window of ``window``
    samples (the ends held), per sample."""
    from scipy.ndimage import uniform_filter1d

    share = np.stack([uniform_filter1d((code == c).astype(float), window, mode="nearest")
                      for c in range(-1, n_codes)])
    return np.argmax(share, axis=0) - 1


def _label_effect(d: Design, _resid, rows) -> Effect:
    """Per-surface change of the rolling coefficient read from the recording's labels, at
    the labels' delay (``label_lag``); the baseline's rolling coefficient stands for the
    reference label (``surface_labels``)."""
    rows = np.ones(d.n, bool) if rows is None else rows
    lag = label_lag(d, rows)
    own = surface_labels(d).own
    base = d.base.coefficient("rolling_kg")
    return Effect(_label_columns(d, lag.samples, lag.window_samples),
                  tuple(f"delta_rolling_kg_{s}" for s in own),
                  np.full(len(own), -base), np.full(len(own), np.inf),
                  {"label_lag_s": (lag.lag_s, lag.sd_s)}, scanned=2)  # the delay and the window


def label_lag(d: Design, rows: np.ndarray) -> LabelLag:
    """The labels' delay behind the ground under the wheels and their majority window
    (``LabelLag``). Every delay of whole samples up to ``settings.max_label_lag_s`` is tried:
    the label columns and the baseline's columns are fitted on the training ``rows`` to the
    baseline's residual, and the delay that leaves the least is taken; its standard error is
    half the span of delays within one unit of chi-square (noise variance x autocorrelation
    time) of the best, as for a payload's change time. At a wrong delay each change of
    surface charges the new surface's rolling to the old one's last metres. Then, at that
    delay, the majority window of ``settings.label_windows_s`` that leaves the least. Fitted
    against the baseline alone (not the candidates chosen before it), once per set of rows."""
    key = ("label_lag", hash(np.packbits(rows).tobytes()))
    if key in d.cache:
        return d.cache[key]
    resid = (d.target - d.columns @ d.base.theta)[rows]

    def left(lag: int, window: int = 0) -> float:
        x = np.hstack([d.columns, _label_columns(d, lag, window)])[rows]
        coef = np.linalg.lstsq(x, resid, rcond=None)[0]
        return float(np.sum((resid - x @ coef) ** 2))

    dt = float(np.median(np.diff(d.t_s)))
    most = round(d.settings.max_label_lag_s / dt) if dt > 0 else 0
    lags = np.arange(most + 1) if dt > 0 else np.zeros(1, int)
    ss = np.array([left(int(k)) for k in lags])
    best = int(np.argmin(ss))
    windows = sorted({max(1, round(w / dt)) if dt > 0 else 1
                      for w in d.settings.label_windows_s})
    window = min(windows, key=lambda w: left(int(lags[best]), w))
    tau = autoregressive_inflation(d.target - d.columns @ d.base.theta, d.samples,
                                   d.settings.inflation_block_s)
    near = ss <= ss[best] + float(np.mean(resid**2)) * tau
    sd = max(0.5 * float(np.ptp(lags[near])) * dt, dt)
    d.cache[key] = LabelLag(int(lags[best]), int(window), float(lags[best] * dt), sd)
    return d.cache[key]


def _needs_labels(d: Design):
    """Why the labels cannot be read for per-surface rolling, or None."""
    if "surface" not in d.columns_of:
        return "the recording has no surface column"
    if d.world.map.surfaces:
        return "the map has surfaces (surface_rolling reads them)"
    if "rolling_kg" not in d.base.names:
        return "no rolling term to differ by surface"
    if not surface_labels(d).own:
        share = 100 * (1 - d.settings.min_label_share)
        return f"the surface labels name one surface on {share:.0f} % of the drive"
    return None


def labelled_design(d: Design) -> Design:
    """``d`` with the recording's labels as its map surfaces: each sample's surface code is its
    label's (delayed and taken over the majority window that ``label_lag`` chose on the whole
    run; the reference label -1, the default ground), and the map carries one surface per own
    label (no polygon: the codes come from the labels), so that per-label rolling joins the
    model as the ``surface_rolling`` term and is refitted inside it (``absorb``): a label
    that rolls harder draws power on gentle downhills the baseline's clip called coasting."""
    from shapely.geometry import Polygon

    from orange_plan.world.geomap import Surface

    lag = label_lag(d, np.ones(d.n, bool))
    labels = surface_labels(d)
    code, own = labels.code, labels.own
    if lag.window_samples > 1:
        code = _majority(code, len(own), lag.window_samples)
    code = code[np.minimum(np.arange(d.n) + lag.samples, d.n - 1)]
    world = d.world
    surfaces = tuple(Surface(name, world.default_crr, Polygon()) for name in own)
    state = d.state.with_(surface_code=code)
    return replace(d, samples=replace(d.samples, state=state),
                   world=replace(world, map=replace(world.map, surfaces=surfaces)), cache={})
