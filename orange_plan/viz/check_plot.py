"""Figure of a mission check: the route on the map coloured by homing margin, the point of no
return, and the margin (with energy used, energy to home and reserve) against distance."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from orange_plan.atomic import atomic_path
from orange_plan.errors import InputError
from orange_plan.viz.plan_plot import HOME_COLOUR, draw_map

MARGIN_CMAP = "RdYlGn"
"""Red (no margin) to green (ample margin)."""
PNR_COLOUR = "#7b3294"


def plot_check(world, mission, check, path: str | Path, title: str) -> Path:
    """Write the PNG of a mission check (atomically) and return its path.

    Left: the map (``draw_map``, none when ``world`` is None: a mission in a local frame), the
    route's legs coloured by the homing margin at their ends (colour bar in kJ, red below
    zero, yellow at zero), the waypoints numbered, home, and the point of no return as a cross
    (when the margin runs out before the end). Right: the
    margin, energy used, energy to home and reserve against distance along the route, the
    available energy as a line and the point of no return as a vertical line.

    Parameters
    ----------
    world : ``world.terrain.World`` or None
    mission : ``export.missions_in.Mission`` (for the waypoints' numbers)
    check : ``planning.mission_check.MissionCheck``
    path : PNG file to write (must end in ``.png``)
    title : first title line
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise InputError(f"{path}: the check figure's file name must end in .png")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_map, ax_e) = plt.subplots(1, 2, figsize=(13, 5.6),
                                       gridspec_kw={"width_ratios": [1.1, 1]})
    try:
        _draw_route(fig, ax_map, world, mission, check)
        _draw_margin(ax_e, check)
        fig.suptitle(f"{title}\n{check.energy_J / 1e3:,.1f} ± {check.energy_sd_J / 1e3:,.1f} kJ "
                     f"of {check.energy_available_J / 1e3:,.1f} kJ in "
                     f"{check.duration_s / 60:,.1f} min; reserve {check.reserve_rule}",
                     fontsize=10)
        with atomic_path(path, suffix=".png") as tmp:
            fig.savefig(tmp, dpi=110, bbox_inches="tight", pad_inches=0.15)
    finally:
        plt.close(fig)
    return path


def _route_point(check, distance_m: float) -> np.ndarray:
    """The (x, y) [m] at ``distance_m`` along the route."""
    for leg in check.legs:
        start = leg.distance_m - leg.length_m
        if distance_m <= leg.distance_m + 1e-9:
            t = 0.0 if leg.length_m == 0 else (distance_m - start) / leg.length_m
            a, b = np.array(leg.from_xyz_m[:2]), np.array(leg.to_xyz_m[:2])
            return a + np.clip(t, 0.0, 1.0) * (b - a)
    return np.array(check.legs[-1].to_xyz_m[:2])


def _draw_route(fig, ax, world, mission, check) -> None:
    from matplotlib.collections import LineCollection
    from matplotlib.colors import Normalize

    handles = draw_map(ax, world, home=False) if world is not None else []
    legs = [leg for leg in check.legs if np.hypot(*np.subtract(leg.to_xyz_m[:2],
                                                               leg.from_xyz_m[:2])) > 0]
    segments = [[leg.from_xyz_m[:2], leg.to_xyz_m[:2]] for leg in legs]
    margin_kj = np.array([leg.margin_J for leg in legs]) / 1e3
    span = max(float(np.max(np.abs(margin_kj), initial=0.0)), 1e-3)  # zero is the middle
    lines = LineCollection(segments, cmap=MARGIN_CMAP, norm=Normalize(-span, span),
                           linewidths=2.2, zorder=5)
    lines.set_array(margin_kj)
    ax.add_collection(lines)
    fig.colorbar(lines, ax=ax, shrink=0.8, label="homing margin at the leg's end [kJ]")
    xyz = mission.xyz_m
    ax.plot(xyz[1:, 0], xyz[1:, 1], "o", ms=3, color="0.15", zorder=6)
    step = max(1, len(xyz) // 40)  # every waypoint up to 40, then every n-th
    for i in range(1, len(xyz), step):
        ax.annotate(str(i), xyz[i, :2], textcoords="offset points", xytext=(3, 3),
                    fontsize=6.5, zorder=6)
    handles.append(ax.scatter([xyz[0, 0]], [xyz[0, 1]], marker="*", s=220, c=HOME_COLOUR,
                              edgecolors="k", zorder=7, label="home"))
    pnr = check.point_of_no_return
    if pnr is not None and check.verdict != "fits":  # a mission that fits has none before its end
        p = _route_point(check, pnr[1])
        handles.append(ax.scatter([p[0]], [p[1]], marker="X", s=140, c=PNR_COLOUR,
                                  edgecolors="w", zorder=8,
                                  label=f"point of no return ({pnr[1]:,.0f} m)"))
    every = np.vstack([np.array([leg.from_xyz_m[:2], leg.to_xyz_m[:2]]).reshape(-1, 2)
                       for leg in check.legs])
    pad = 0.05 * max(np.ptp(every[:, 0]), np.ptp(every[:, 1]), 1.0)
    if world is None:
        ax.set_xlim(every[:, 0].min() - pad, every[:, 0].max() + pad)
        ax.set_ylim(every[:, 1].min() - pad, every[:, 1].max() + pad)
        ax.set_aspect("equal")
    ax.set_xlabel("x east [m]")
    ax.set_ylabel("y north [m]")
    ax.legend(handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(0.0, -0.14),
              ncol=3, frameon=False)


def _draw_margin(ax, check) -> None:
    d = np.r_[0.0, [leg.distance_m for leg in check.legs]]
    kj = 1e-3
    margin = np.r_[check.start_margin_J, [leg.margin_J for leg in check.legs]] * kj
    used = np.r_[0.0, [leg.energy_used_J for leg in check.legs]] * kj
    home = np.r_[0.0, [leg.energy_to_home_J for leg in check.legs]] * kj
    reserve = np.r_[check.energy_available_J - check.start_margin_J,
                    [leg.reserve_J for leg in check.legs]] * kj
    ax.axhline(check.energy_available_J * kj, color="0.3", ls="--", lw=1,
               label="energy available")
    ax.axhline(0.0, color="k", lw=0.8)
    ax.plot(d, used, color="#1f77b4", label="energy used")
    ax.plot(d, home, color="#ff7f0e", label="energy to home")
    ax.plot(d, reserve, color="0.5", lw=1, label="reserve")
    ax.plot(d, margin, color="#2ca02c", lw=2, label="homing margin")
    ax.fill_between(d, margin, 0.0, where=margin < 0, color="#d62728", alpha=0.3,
                    interpolate=True, label="margin below zero")
    pnr = check.point_of_no_return
    if pnr is not None and check.verdict != "fits":
        ax.axvline(pnr[1], color=PNR_COLOUR, ls=":", lw=1.5, label="point of no return")
    ax.set_xlabel("distance along the route [m]")
    ax.set_ylabel("energy [kJ]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(0.0, -0.14), ncol=3,
              frameon=False)
