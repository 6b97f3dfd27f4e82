"""Figure: offline vs online operational range estimates over a simulated run to depletion."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from orange_plan.atomic import save_figure


def plot_online_traces(traces, path: str | Path) -> Path:
    """One panel per run: true range, the offline (a priori) estimate and the online estimate
    (distance so far + remaining range, with a 2-sigma band), against mission time.

    Parameters
    ----------
    traces : ``bench.identify.OnlineTrace`` objects
    path : PNG to write (atomically: temporary file, then rename)
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(traces)
    cols = min(2, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(6 * cols, 3.6 * rows), squeeze=False)
    for ax, tr in zip(axes.ravel(), traces):
        frac = 100 * tr.t_s / tr.duration_s
        ax.axhline(tr.d_true_m, color="k", lw=1.5, label="true range (depletion)")
        ax.axhline(tr.d_offline_m, color="tab:red", ls="--", label="offline ORangE (a priori)")
        ax.plot(frac, tr.range_total_m, color="tab:blue", label="online ORangE")
        ax.fill_between(frac, tr.range_total_m - 2 * tr.range_sd_m,
                        tr.range_total_m + 2 * tr.range_sd_m, color="tab:blue", alpha=0.2,
                        label="online ± 2 sd (parameters)")
        ax.set_ylim(0.7 * tr.d_true_m, 1.3 * tr.d_true_m)
        ax.set_xlim(0, 100)
        ax.set_title(tr.scenario, fontsize=10)
        ax.set_xlabel("mission time [% of run]")
        ax.set_ylabel("estimated range [m]")
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    axes.ravel()[0].legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)
