"""viz.reach_plot: every label of the reach figure is readable (inside, not overlapped)."""

from __future__ import annotations

import pytest
from planning_worlds import write_world

from orange_plan.context import load_context
from orange_plan.planning.reach import prepare_reach, query_goals, query_points
from orange_plan.viz.reach_plot import field_grid, reach_figure

pytestmark = pytest.mark.timeout(60)


def test_goal_labels_stay_in_the_axes_and_the_legend_clears_the_x_label(tmp_path):
    ctx = load_context(write_world(tmp_path, obstacles=[(10, 5, 14, 25)], surfaces=[
        (20, 0, 40, 15, 0.1), (0, 20, 10, 30, 0.2)]))
    reach = prepare_reach(ctx, n_vertices=150, seed=1)
    # "outside" lies beyond the boundary and so sets the right edge of the view
    goals = query_goals(reach, [[35.0, 25.0], [12.0, 10.0], [60.0, 5.0], [1.0, 29.0]],
                        ["far", "in_box", "outside", "corner"])
    xs, ys, points = field_grid(ctx.world, max_points=2000)
    fig = reach_figure(reach, query_points(reach, points), xs, ys, goals, "title")
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    ax = fig.axes[0]
    axes_box, fig_box = ax.get_window_extent(renderer), fig.bbox
    labels = [t for t in ax.texts if t.get_text() in ("far", "in_box", "outside", "corner")]
    assert len(labels) == 4
    for text in labels:
        box = text.get_window_extent(renderer)
        assert axes_box.x0 <= box.x0 and box.x1 <= axes_box.x1, text.get_text()
        assert axes_box.y0 <= box.y0 and box.y1 <= axes_box.y1, text.get_text()
    (legend,) = fig.legends
    legend_box = legend.get_window_extent(renderer)
    assert fig_box.x0 <= legend_box.x0 and legend_box.x1 <= fig_box.x1
    assert fig_box.y0 <= legend_box.y0 and legend_box.y1 <= fig_box.y1
    assert not legend_box.overlaps(ax.xaxis.label.get_window_extent(renderer))
