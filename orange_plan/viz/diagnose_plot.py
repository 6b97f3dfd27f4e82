"""Figure of a diagnosis: every located window as a bar on the time axis, the residual before
and after over time; the residual against each implicated feature, with the fitted term
drawn over it. Time is in seconds throughout, as in the table."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from orange_plan.atomic import save_figure

MAX_POINTS = 4000
"""Scatter points drawn per panel (an even subsample: a 10 Hz hour has 36,000)."""


def plot_diagnosis(result, path: str | Path, title: str = "") -> Path:
    """Write the diagnosis PNG (atomically) for an ``identify.diagnosis.Diagnosis``."""
    return save_figure(diagnosis_figure(result, title), path)


def diagnosis_figure(result, title: str = ""):
    """The diagnosis figure (matplotlib Figure)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = result.design
    panels = result.feature_panels()
    rows = max(1, len(result.mismatches))
    strip_in = 0.25 + 0.22 * rows  # one bar per listed window [in]
    fig = plt.figure(figsize=(11, 7.5 + strip_in))
    grid = fig.add_gridspec(3, max(1, len(panels)), height_ratios=[strip_in, 4.0, 3.6])
    time_ax = fig.add_subplot(grid[1, :])
    _windows_strip(fig.add_subplot(grid[0, :], sharex=time_ax), result)
    _time_panel(time_ax, result)
    for k, (label, feature, resid, fitted, name) in enumerate(panels):
        ax = fig.add_subplot(grid[2, k])
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


def _windows_strip(ax, result) -> None:
    """Every listed window as a shaded bar on the time axis, in the order of the table, with
    its condition: windows can overlap or span most of the run, so each gets its own row
    (shading them all on the residual panel would cover it)."""
    rows = result.mismatches
    t = result.design.t_s
    middle = 0.5 * (t[0] + t[-1])
    for k, m in enumerate(rows):
        colour = "tab:red" if m.mean_residual_W > 0 else "tab:blue"
        ax.barh(k, m.t_end_s - m.t_start_s, left=m.t_start_s, height=0.7, color=colour,
                alpha=0.3, edgecolor=colour, lw=0.8, gid="located-window")
        text = f" {m.where} ({m.mean_residual_W:+.3g} W) "
        if m.t_start_s > middle:  # a late window: its words run left, inside the axes
            ax.text(m.t_end_s, k, text, va="center", ha="right", fontsize=7.5, clip_on=True)
        else:
            ax.text(m.t_start_s, k, text, va="center", ha="left", fontsize=7.5, clip_on=True)
    if not rows:
        ax.text(0.5, 0.5, "no located windows", transform=ax.transAxes, ha="center",
                va="center", fontsize=8, color="0.4")
    ax.set_ylim(max(len(rows), 1) - 0.5, -0.5)  # first row on top, as in the table
    ax.set_yticks([])
    ax.tick_params(labelbottom=False)
    ax.set_title("located windows, as listed (red: recorded above the baseline, blue: below)",
                 fontsize=9)


def _time_panel(ax, result) -> None:
    """Residual 1 s means before and after against time [s] (the table's unit)."""
    edges, mean_before, mean_after = result.residual_per_second()
    t_s = edges[:-1]
    ax.plot(t_s, mean_before, color="0.35", lw=0.8,
            label=f"before: baseline (RMSE {result.baseline.rmse_W:.3g} W)")
    ax.plot(t_s, mean_after, color="tab:blue", lw=0.9,
            label=f"after: with the found terms (RMSE {result.improved.rmse_W:.3g} W)")
    ax.axhline(0.0, color="0.2", lw=0.6)
    ax.set_xlabel("time since start [s]")
    ax.set_ylabel("residual, 1 s means [W]")
    ax.set_title(f"{result.verdict}: " + (", ".join(
        f.term + (f" ({f.variant})" if f.variant else "") for f in result.findings) or
        "nothing added"), fontsize=10)
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
