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
    return save_figure(replay_figure(replay, cumulative_recorded_J, cumulative_predicted_J,
                                     title), path)


# The prediction is drawn as a broad translucent band under a thin recorded line: where the
# model fits, the two coincide and the recording must still show (it is the measurement).
RECORDED_STYLE = {"color": "0.15", "lw": 0.7, "zorder": 3}
PREDICTED_STYLE = {"color": "tab:orange", "lw": 2.4, "alpha": 0.55, "zorder": 2}


def replay_figure(replay, cumulative_recorded_J, cumulative_predicted_J, title: str = ""):
    """The replay figure (matplotlib Figure; parameters as ``plot_replay``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t_min = np.asarray(replay.t_s) / 60.0
    fig, (ax_p, ax_e) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True,
                                     gridspec_kw={"height_ratios": [3, 2]})
    ax_p.plot(t_min, replay.recorded_W, label="recorded", **RECORDED_STYLE)
    ax_p.plot(t_min, replay.predicted_W, label=f"predicted (RMSE {replay.rmse_W:,.1f} W)",
              **PREDICTED_STYLE)
    ax_p.set_ylabel("battery power [W]")
    ax_p.legend(loc="upper right", fontsize=9)
    ax_p.grid(alpha=0.3)
    wh = 1.0 / 3600.0
    ax_e.plot(t_min, np.asarray(cumulative_recorded_J) * wh,
              label=f"recorded {replay.energy_recorded_J * wh:,.2f} Wh", **RECORDED_STYLE)
    ax_e.plot(t_min, np.asarray(cumulative_predicted_J) * wh,
              label=f"predicted {replay.energy_predicted_J * wh:,.2f} Wh "
                    f"({replay.energy_error_pct:+.1f} %)", **PREDICTED_STYLE)
    ax_e.set_ylabel("cumulative energy [Wh]")
    ax_e.set_xlabel("time [min]")
    ax_e.legend(loc="upper left", fontsize=9)
    ax_e.grid(alpha=0.3)
    fig.suptitle(title or "recorded vs predicted battery power")
    fig.tight_layout()
    return fig
