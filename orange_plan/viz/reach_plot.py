"""Figure of a reach analysis: the margin over the map, home, obstacles, surfaces, goals."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from orange_plan.atomic import save_figure

MAX_FIELD_POINTS = 40_000
"""Points of the margin image (the field is queried at each, ~20 us per point)."""


def field_grid(world, max_points: int = MAX_FIELD_POINTS):
    """Regular grid of points over the boundary box: (xs, ys, points (ny*nx, 2))."""
    xmin, ymin, xmax, ymax = world.true_map.boundary.bounds
    cell = np.sqrt((xmax - xmin) * (ymax - ymin) / max_points)
    xs = np.arange(xmin + cell / 2, xmax, cell)
    ys = np.arange(ymin + cell / 2, ymax, cell)
    gx, gy = np.meshgrid(xs, ys)
    return xs, ys, np.stack([gx.ravel(), gy.ravel()], axis=1)


def plot_reach(reach, field, xs, ys, goals, path: str | Path, title: str) -> Path:
    """Write the reach PNG (atomically).

    Parameters
    ----------
    reach : planning.reach.Reachability
    field : planning.reach.PointsReach at the grid points of ``xs`` x ``ys``
    goals : list of GoalResult (may be empty)
    path : PNG file
    title : figure title (scenario, energy used)
    """
    return save_figure(reach_figure(reach, field, xs, ys, goals, title), path)


def reach_figure(reach, field, xs, ys, goals, title: str):
    """The reach figure (matplotlib Figure; parameters as ``plot_reach``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    world = reach.exact.world
    shape = (len(ys), len(xs))
    margin_kJ = field.margin_J.reshape(shape) / 1e3
    ok = field.valid.reshape(shape) & np.isfinite(margin_kJ)
    feasible = ok & (margin_kJ >= 0)
    # constrained layout makes room for the legend below the axes (under the x label)
    fig, ax = plt.subplots(figsize=(9, 7.5), layout="constrained")
    extent = (xs[0] - (xs[1] - xs[0]) / 2, xs[-1] + (xs[1] - xs[0]) / 2,
              ys[0] - (ys[1] - ys[0]) / 2, ys[-1] + (ys[1] - ys[0]) / 2)
    shown = np.where(feasible, margin_kJ, np.nan)
    vmax = np.nanmax(shown) if np.any(feasible) else 1.0
    # With an infeasible region, 0 kJ (its edge) anchors the scale; otherwise the scale spans
    # the margins present so that their variation stays visible.
    vmin = 0.0 if np.any(ok & ~feasible) or not np.any(feasible) else np.nanmin(shown)
    image = ax.imshow(shown, origin="lower", extent=extent, cmap="viridis", vmin=vmin,
                      vmax=max(vmax, vmin + 1e-9),
                      interpolation="nearest", zorder=1)
    infeasible = np.where(ok & ~feasible, 1.0, np.nan)
    ax.imshow(infeasible, origin="lower", extent=extent, zorder=1, interpolation="nearest",
              cmap=ListedColormap(["#d9a3a3"]))
    fig.colorbar(image, ax=ax, shrink=0.85, label="margin after the round trip and reserve [kJ]")

    dem = world.map.elevation
    if dem is not None:
        gx, gy = np.meshgrid(xs, ys)
        cs = ax.contour(gx, gy, world.elevation_at(gx, gy), levels=8, colors="white",
                        linewidths=0.6, alpha=0.7, zorder=2)
        ax.clabel(cs, fontsize=7, fmt="%.0f m")
    palette = plt.get_cmap("tab10")
    names = world.map.surface_names
    for s in world.map.surfaces:
        colour = palette((names.index(s.name) + 3) % 10)
        for poly in getattr(s.polygon, "geoms", [s.polygon]):
            ax.plot(*poly.exterior.xy, color=colour, lw=1.0, zorder=3)
    for zone in (*world.true_map.obstacles, *world.true_map.no_go):  # as given, not inflated
        for poly in getattr(zone, "geoms", [zone]):
            ax.fill(*poly.exterior.xy, color="0.25", zorder=4)
    ax.plot(*world.true_map.boundary.exterior.xy, color="black", lw=1.5, zorder=4)

    hx, hy = reach.home_xy_m
    ax.plot(hx, hy, marker="*", ms=18, color="gold", mec="black", zorder=6)
    handles = [Line2D([], [], marker="*", ms=14, color="gold", mec="black", ls="", label="home"),
               Patch(color="0.25", label="obstacle / no-go"),
               Patch(color="#d9a3a3", label="cannot return with reserve")]
    if reach.start_index != reach.roadmap.home_index:
        sx, sy = reach.start_xy_m
        ax.plot(sx, sy, marker="o", ms=10, color="white", mec="black", zorder=6)
        handles.append(Line2D([], [], marker="o", color="white", mec="black", ls="",
                              label="robot (--from)"))
    for s_name in names:
        handles.append(Line2D([], [], color=palette((names.index(s_name) + 3) % 10),
                              label=f"surface: {s_name}"))
    for g in goals:
        style = ("o", "limegreen") if g.feasible else (("X", "red") if g.valid else ("x", "black"))
        ax.plot(g.x_m, g.y_m, marker=style[0], ms=9, color=style[1], mec="black", zorder=7)
        if g.path_xy_m is not None and g.feasible:
            ax.plot(*g.path_xy_m.T, color="white", lw=0.8, alpha=0.8, zorder=5)
    if goals:
        handles += [Line2D([], [], marker="o", color="limegreen", mec="black", ls="",
                           label="goal: feasible"),
                    Line2D([], [], marker="X", color="red", mec="black", ls="",
                           label="goal: infeasible"),
                    Line2D([], [], marker="x", color="black", ls="", label="goal: invalid")]
    fig.legend(handles=handles, loc="outside lower center", ncol=3, fontsize=8, frameon=False)
    bx0, by0, bx1, by1 = world.true_map.boundary.bounds
    gx_all = [bx0, bx1, *(g.x_m for g in goals)]
    gy_all = [by0, by1, *(g.y_m for g in goals)]
    pad = 0.02 * max(bx1 - bx0, by1 - by0)
    ax.set_xlim(min(gx_all) - (pad if len(goals) else 0), max(gx_all) + (pad if len(goals) else 0))
    ax.set_ylim(min(gy_all) - (pad if len(goals) else 0), max(gy_all) + (pad if len(goals) else 0))
    _label_goals(ax, goals)
    ax.set_xlabel("x [m] (east)")
    ax.set_ylabel("y [m] (north)")
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=10)
    return fig


def _label_goals(ax, goals) -> None:
    """Name each goal on the side facing the middle of the view, so a goal at the edge (one
    outside the boundary sets the view's edge) keeps its label inside the axes."""
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    for g in goals:
        if not g.name:
            continue
        right = g.x_m > 0.5 * (x0 + x1)
        top = g.y_m > 0.5 * (y0 + y1)
        ax.annotate(g.name, (g.x_m, g.y_m), xytext=(-6 if right else 6, -6 if top else 6),
                    textcoords="offset points", ha="right" if right else "left",
                    va="top" if top else "bottom", fontsize=8, zorder=8)
