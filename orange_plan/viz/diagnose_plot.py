"""Figure of a diagnosis: the residual before and after over time, with the located windows
shaded; the residual against each implicated feature, with the fitted term drawn over it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from orange_plan.atomic import save_figure

MAX_POINTS = 4000
"""Scatter points drawn per panel (an even subsample: a 10 Hz hour has 36,000)."""


def plot_diagnosis(result, path: str | Path, title: str = "") -> Path:
    """Write the diagnosis PNG (atomically) for an ``identify.diagnose.Diagnosis``."""
    return save_figure(diagnosis_figure(result, title), path)


def diagnosis_figure(result, title: str = ""):
    """The diagnosis figure (matplotlib Figure)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = result.design
    panels = result.feature_panels()
    fig = plt.figure(figsize=(11, 7.5))
    grid = fig.add_gridspec(2, max(1, len(panels)), height_ratios=[1.1, 1])
    _time_panel(fig.add_subplot(grid[0, :]), result)
    for k, (label, feature, resid, fitted, name) in enumerate(panels):
        ax = fig.add_subplot(grid[1, k])
        pick = np.linspace(0, d.n - 1, min(d.n, MAX_POINTS)).astype(int)
        ax.scatter(feature[pick], resid[pick], s=3, color="0.55", alpha=0.35,
                   label="residual without this term" if fitted is not None
                   else "baseline residual", rasterized=True)
        centres, means = _binned(feature, resid)
        ax.plot(centres, means, "o-", color="0.1", ms=3, lw=1.2, label="residual, binned mean")
        if fitted is not None:
            c2, m2 = _binned(feature, fitted)
            ax.plot(c2, m2, "-", color="tab:orange", lw=2.4, label=f"fitted {name}")
        ax.axhline(0.0, color="0.3", lw=0.6)
        ax.set_xlabel(label)
        ax.set_ylabel("recorded - predicted [W]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
        lo, hi = np.percentile(resid, [0.5, 99.5])
        lo, hi = min(lo, float(np.min(means))), max(hi, float(np.max(means)))
        pad = 0.1 * (hi - lo + 1e-9)
        ax.set_ylim(lo - pad, hi + pad)
    fig.suptitle(title or "diagnosis")
    fig.tight_layout()
    return fig


def _time_panel(ax, result) -> None:
    d = result.design
    edges, mean_before, mean_after = result.residual_per_second()
    t_min = edges[:-1] / 60.0
    span = d.t_s[-1] - d.t_s[0]
    for m in result.mismatches:
        if m.t_end_s - m.t_start_s < 0.5 * span:  # condition-wide spans would shade everything
            ax.axvspan(m.t_start_s / 60.0, m.t_end_s / 60.0, color="tab:red", alpha=0.12, lw=0)
    ax.plot(t_min, mean_before, color="0.35", lw=0.8,
            label=f"before: baseline (RMSE {result.baseline.rmse_W:.3g} W)")
    ax.plot(t_min, mean_after, color="tab:blue", lw=0.9,
            label=f"after: with the found terms (RMSE {result.improved.rmse_W:.3g} W)")
    ax.axhline(0.0, color="0.2", lw=0.6)
    ax.set_xlabel("time [min]")
    ax.set_ylabel("residual, 1 s means [W]")
    ax.set_title(f"{result.verdict}: " + (", ".join(
        f.term + (f" ({f.variant})" if f.variant else "") for f in result.findings) or
        "nothing added") + "   (shaded: located windows)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")


def _binned(x: np.ndarray, y: np.ndarray, bins: int = 24, least: int = 3):
    """Mean of y in equal-width bins of x (bins with fewer than ``least`` samples left out:
    a feature that is mostly 0, like a yaw rate, still shows its whole range)."""
    lo, hi = float(np.min(x)), float(np.max(x))
    if hi <= lo:
        return np.array([lo]), np.array([float(np.mean(y))])
    which = np.minimum(((x - lo) / (hi - lo) * bins).astype(int), bins - 1)
    n = np.bincount(which, minlength=bins)
    keep = n >= least
    cx = np.bincount(which, x, minlength=bins)[keep] / n[keep]
    cy = np.bincount(which, y, minlength=bins)[keep] / n[keep]
    return cx, cy
