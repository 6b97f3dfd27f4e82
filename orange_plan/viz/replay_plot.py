"""Figure of a replay: recorded vs predicted battery power, and cumulative energy."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from orange_plan.atomic import save_figure


def plot_replay(replay, cumulative_recorded_J, cumulative_predicted_J, path: str | Path,
                title: str = "") -> Path:
    """Write a two-panel PNG: power over time (top) and cumulative energy (bottom).

    Parameters
    ----------
    replay : a ``telemetry.replay.Replay``
    cumulative_recorded_J, cumulative_predicted_J : running energy per sample [J]
    path : PNG to write (atomically: temporary file, then rename)
    title : figure title
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t_min = np.asarray(replay.t_s) / 60.0
    fig, (ax_p, ax_e) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True,
                                     gridspec_kw={"height_ratios": [3, 2]})
    ax_p.plot(t_min, replay.recorded_W, lw=0.7, color="0.35", label="recorded")
    ax_p.plot(t_min, replay.predicted_W, lw=0.9, color="tab:orange", alpha=0.85,
              label=f"predicted (RMSE {replay.rmse_W:,.1f} W)")
    ax_p.set_ylabel("battery power [W]")
    ax_p.legend(loc="upper right", fontsize=9)
    ax_p.grid(alpha=0.3)
    wh = 1.0 / 3600.0
    ax_e.plot(t_min, np.asarray(cumulative_recorded_J) * wh, color="0.35",
              label=f"recorded {replay.energy_recorded_J * wh:,.2f} Wh")
    ax_e.plot(t_min, np.asarray(cumulative_predicted_J) * wh, color="tab:orange",
              label=f"predicted {replay.energy_predicted_J * wh:,.2f} Wh "
                    f"({replay.energy_error_pct:+.1f} %)")
    ax_e.set_ylabel("cumulative energy [Wh]")
    ax_e.set_xlabel("time [min]")
    ax_e.legend(loc="upper left", fontsize=9)
    ax_e.grid(alpha=0.3)
    fig.suptitle(title or "recorded vs predicted battery power")
    fig.tight_layout()
    return save_figure(fig, path)
