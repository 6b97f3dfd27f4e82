"""viz.replay_plot: the recorded line stays visible where the prediction matches it."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from orange_plan.viz.replay_plot import replay_figure


def test_recorded_line_is_drawn_over_the_prediction():
    t = np.arange(0.0, 60.0, 0.1)
    power = 20.0 + np.sin(t)
    replay = SimpleNamespace(t_s=t, recorded_W=power, predicted_W=power, rmse_W=0.0,
                             energy_recorded_J=1.0, energy_predicted_J=1.0, energy_error_pct=0.0)
    energy = np.cumsum(power) * 0.1
    fig = replay_figure(replay, energy, energy, "identical")
    for ax in fig.axes:
        recorded, predicted = ax.get_lines()
        assert recorded.get_label().startswith("recorded")
        assert predicted.get_label().startswith("predicted")
        # on top, and thinner than the band under it: both show where they coincide
        assert recorded.get_zorder() > predicted.get_zorder()
        assert recorded.get_linewidth() < predicted.get_linewidth()
