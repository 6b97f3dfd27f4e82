"""Figure of an exploration plan: the map, the tour coloured by speed, the covered area, home,
and the energy budget (used, to home, reserve, homing margin) against mission time.

``draw_map`` draws the map alone (boundary, elevation shading, surfaces, obstacles, no-go
zones, home) onto any matplotlib axes, so that other figures and pages can put their own
layers on top. Layers use these z-orders, leaving room in between for callers:

====  ===========================================================
0     elevation hillshade (clipped to the boundary)
1     surface fills (translucent, so the shading shows through)
1.5   elevation contour lines and their labels
2-3   free for area overlays (``plot_plan`` puts the covered area at 2.5)
3.5   surface outlines (``surfaces="outline"``)
4     obstacles (dark grey) and no-go zones (hatched red)
4.5   boundary outline
5     free for paths (``plot_plan`` puts the tour at 5)
7     home star
====  ===========================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely

from orange_plan.atomic import atomic_path
from orange_plan.errors import InputError

MAX_SHADE_CELLS = 400
"""Grid cells per side of the elevation hillshade and contours (fast on any map size)."""

WAYPOINT_LABEL_PT = (4.5, 7.0)
"""Smallest and largest type of the waypoints' numbers [pt]: every waypoint is numbered, in
type as large as their spacing on the drawn map leaves room for (``_label_size``)."""

SURFACE_COLOURS = ("#fdbf6f", "#cab2d6", "#b2df8a", "#fb9a99", "#ffff99", "#e5c494",
                   "#d9d9d9", "#fccde5", "#bc80bd", "#ccebc5")
"""Light, mutually distinct fills for surfaces, by order of first appearance of the name.
No blues: blue is kept for the covered area (and water-like overlays) drawn on top."""
DEFAULT_SURFACE_COLOUR = "#f3efe2"
OBSTACLE_COLOUR = "0.3"
NO_GO_COLOUR = "#d62728"
COVERED_COLOUR = "#1f77b4"
COVERED_EDGE = "#0b3c6e"
HOME_COLOUR = "gold"
TOUR_CMAP = "plasma"


# --------------------------------------------------------------------------------------
# Map
# --------------------------------------------------------------------------------------
CONTINUATION = "#d95f02"
"""Colour of the closed loop's expected route beyond the guaranteed tour."""


def draw_map(ax, world, *, home: bool = True, shading: bool = True,
             surfaces: str = "fill") -> list:
    """Draw a map on ``ax`` in metres with equal aspect and return its legend handles.

    Parameters
    ----------
    ax : matplotlib Axes
    world : ``world.terrain.World`` (its map, default surface and home) or a bare
        ``world.geomap.Map`` (then the map's own default surface and home are used)
    home : draw the home point as a star
    shading : draw the elevation raster (hillshade and contour lines) when the map has one
    surfaces : "fill" (light translucent fills, the default ground included) or "outline"
        (coloured edges above area overlays, no fills: for figures whose own image, such as
        a margin field, covers the map)

    Returns
    -------
    list of matplotlib artists for ``ax.legend(handles=...)``: one entry per surface name
    (with its crr), the default surface, obstacles, no-go zones, elevation contours and
    home, each only when the map has it. The caller places the legend (outside the map
    is best: it then hides nothing).
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    if surfaces not in ("fill", "outline"):
        raise ValueError(f"surfaces must be 'fill' or 'outline', not {surfaces!r}")
    fill = surfaces == "fill"
    m = getattr(world, "true_map", world)  # the map as given, not inflated by the keep-away
    if hasattr(world, "map"):
        default_name, default_crr = world.default_surface_name, world.default_crr
        home_xy = world.home_xy_m
    else:
        default_name, default_crr = m.default_surface or (None, None)
        home_xy = m.home_xy_m
    handles: list = []
    boundary_patch = _patch(m.boundary, facecolor="none", edgecolor="none")
    ax.add_patch(boundary_patch)  # invisible; clips the hillshade to the workspace

    # Default surface: the ground wherever no surface polygon applies. Only shown when the
    # map names one or has surfaces to tell it apart from (a bare map stays white).
    show_default = fill and (m.default_surface is not None or bool(m.surfaces))
    if show_default:
        ax.add_patch(_patch(m.boundary, facecolor=DEFAULT_SURFACE_COLOUR, edgecolor="none",
                            alpha=0.6 if _has_relief(m) and shading else 1.0, zorder=1))
        if default_crr is None:  # a bare Map with surfaces but no default_surface
            label = "elsewhere: the robot's crr"
        elif default_name == "default":
            label = f"default ground, crr {default_crr:g}"
        else:
            label = f"{default_name} (default), crr {default_crr:g}"
        handles.append(Patch(facecolor=DEFAULT_SURFACE_COLOUR, edgecolor="0.6", label=label))

    if shading and m.elevation is not None:
        handles += _draw_elevation(ax, m, boundary_patch)

    names = m.surface_names
    for s in m.surfaces:
        colour = SURFACE_COLOURS[names.index(s.name) % len(SURFACE_COLOURS)]
        if fill:
            ax.add_patch(_patch(s.polygon, facecolor=colour, edgecolor="none",
                                alpha=0.55 if _has_relief(m) and shading else 0.75, zorder=1))
        else:
            ax.add_patch(_patch(s.polygon, facecolor="none", edgecolor=_darker(colour),
                                lw=1.2, zorder=3.5))
    for name in names:
        crrs = sorted({s.crr for s in m.surfaces if s.name == name})
        colour = SURFACE_COLOURS[names.index(name) % len(SURFACE_COLOURS)]
        label = f"{name}, crr {'/'.join(f'{c:g}' for c in crrs)}"
        handles.append(Patch(facecolor=colour, edgecolor="0.6", label=label) if fill else
                       Patch(facecolor="none", edgecolor=_darker(colour), lw=1.2, label=label))

    for zone in m.obstacles:
        ax.add_patch(_patch(zone, facecolor=OBSTACLE_COLOUR, edgecolor=OBSTACLE_COLOUR,
                            lw=0.5, zorder=4))
    if m.obstacles:
        handles.append(Patch(facecolor=OBSTACLE_COLOUR, label="obstacle"))
    for zone in m.no_go:
        # The hatch takes the edge colour; the fill is a light wash of the same red.
        ax.add_patch(_patch(zone, facecolor=(0.84, 0.15, 0.16, 0.15), edgecolor=NO_GO_COLOUR,
                            hatch="///", lw=1.0, zorder=4))
    if m.no_go:
        handles.append(Patch(facecolor=(0.84, 0.15, 0.16, 0.15), edgecolor=NO_GO_COLOUR,
                             hatch="///", label="no-go zone"))

    ax.add_patch(_patch(m.boundary, facecolor="none", edgecolor="black", lw=1.5, zorder=4.5))
    if home and home_xy is not None:
        ax.plot(*home_xy, marker="*", ms=18, color=HOME_COLOUR, mec="black", mew=1.0, ls="",
                zorder=7)
        handles.append(Line2D([], [], marker="*", ms=14, color=HOME_COLOUR, mec="black", ls="",
                              label="home"))

    xmin, ymin, xmax, ymax = m.boundary.bounds
    pad = 0.025 * max(xmax - xmin, ymax - ymin)  # room for markers on the boundary
    ax.set_xlim(xmin - pad, xmax + pad)
    ax.set_ylim(ymin - pad, ymax + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m] (east)")
    ax.set_ylabel("y [m] (north)")
    return handles


def _darker(colour, factor: float = 0.6):
    """The same hue, darker (light fills become readable outlines)."""
    from matplotlib.colors import to_rgb

    return tuple(factor * c for c in to_rgb(colour))


def _has_relief(m) -> bool:
    return m.elevation is not None and float(np.ptp(m.elevation.z_m)) > 1e-6


def _draw_elevation(ax, m, clip_patch) -> list:
    """Hillshade (grey) under everything and labelled contour lines; returns legend handles."""
    from matplotlib.colors import LightSource
    from matplotlib.lines import Line2D

    xmin, ymin, xmax, ymax = m.boundary.bounds
    cell = max(m.elevation.cell_m, max(xmax - xmin, ymax - ymin) / MAX_SHADE_CELLS)
    xs = np.arange(xmin + cell / 2, xmax, cell)
    ys = np.arange(ymin + cell / 2, ymax, cell)
    if len(xs) < 2 or len(ys) < 2:
        return []
    gx, gy = np.meshgrid(xs, ys)
    z = m.elevation.elevation_at(gx, gy)
    relief = float(np.ptp(z))
    if relief <= 1e-6:
        return []  # flat raster: nothing to shade
    # Exaggerate gentle terrain until its steeper slopes show: the 95th percentile slope
    # is drawn as if it were ~1 (45 deg), never flattened below the true relief.
    gz_y, gz_x = np.gradient(z, cell)
    steep = float(np.percentile(np.hypot(gz_x, gz_y), 95))
    exaggeration = float(np.clip(1.0 / max(steep, 1e-9), 1.0, 1e4))
    shade = LightSource(azdeg=315, altdeg=45).hillshade(z, vert_exag=exaggeration,
                                                         dx=cell, dy=cell)
    image = ax.imshow(shade, origin="lower", cmap="gray", vmin=-0.3, vmax=1.15,
                      extent=(xs[0] - cell / 2, xs[-1] + cell / 2,
                              ys[0] - cell / 2, ys[-1] + cell / 2),
                      interpolation="bilinear", zorder=0)
    image.set_clip_path(clip_patch)
    levels = _nice_levels(float(z.min()), float(z.max()))
    cs = ax.contour(gx, gy, z, levels=levels, colors="#6b4f2a", linewidths=0.6, alpha=0.8,
                    zorder=1.5)
    cs.set_clip_path(clip_patch)
    fmt = "%.0f m" if relief >= 5 else "%.1f m"
    ax.clabel(cs, levels[::2] if len(levels) > 6 else levels, fontsize=7, fmt=fmt,
              inline_spacing=2)
    step = levels[1] - levels[0] if len(levels) > 1 else relief
    return [Line2D([], [], color="#6b4f2a", lw=0.8,
                   label=f"elevation contour, every {step:g} m")]


def _nice_levels(lo: float, hi: float, target: int = 10) -> np.ndarray:
    """Round contour levels (1, 2, 2.5 or 5 x 10^k apart) strictly inside (lo, hi)."""
    raw = (hi - lo) / target
    mag = 10 ** np.floor(np.log10(raw))
    step = min((s * mag for s in (1, 2, 2.5, 5, 10)), key=lambda s: abs(s - raw))
    levels = np.arange(np.ceil(lo / step) * step, hi, step)
    levels = levels[(levels > lo) & (levels < hi)]
    return levels if len(levels) else np.array([(lo + hi) / 2])


def _patch(geom, **kw):
    """One PathPatch for a (Multi)Polygon or collection (holes kept; non-areal parts dropped)."""
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path as MplPath

    paths = []
    for poly in _polygons(geom):
        for ring in (poly.exterior, *poly.interiors):
            xy = np.asarray(ring.coords)
            if len(xy) >= 3:
                codes = np.full(len(xy), MplPath.LINETO, dtype=np.uint8)
                codes[0], codes[-1] = MplPath.MOVETO, MplPath.CLOSEPOLY
                paths.append(MplPath(xy, codes))
    path = MplPath.make_compound_path(*paths) if paths else MplPath(np.zeros((0, 2)))
    return PathPatch(path, **kw)


def _polygons(geom) -> list:
    if geom is None or geom.is_empty:
        return []
    if geom.geom_type == "Polygon":
        return [geom]
    return [p for g in getattr(geom, "geoms", []) for p in _polygons(g)]


# --------------------------------------------------------------------------------------
# Plan
# --------------------------------------------------------------------------------------
def plot_plan(world, plan, path: str | Path, title: str) -> Path:
    """Write the PNG of an exploration plan (atomically) and return its path.

    Left: the map (``draw_map``), the covered area, the tour coloured by its commanded speed
    (colour bar in m/s; one colour and the speed in the legend when the speed is constant),
    every waypoint numbered in visiting order (from 0, as the GeoJSON's ``order``; the type
    shrinks where waypoints are dense, ``WAYPOINT_LABEL_PT``), the start when it is not home,
    and home. Right: energy used, energy to home, reserve and homing margin against
    mission time, with the available energy as a horizontal line. The title gives coverage
    (m^2 and % of the free area), energy planned / available and the return probability.

    Parameters
    ----------
    world : ``world.terrain.World`` the plan was made in
    plan : ``planning.plan.Plan``
    path : PNG file to write; must end in ``.png``. Written via a temporary file and a
        rename: on any error no file (partial or temporary) is left and an existing file
        is kept.
    title : first title line (scenario name, ...)

    Raises
    ------
    InputError
        If ``path`` does not end in ``.png`` or the plan's per-vertex arrays disagree in length.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise InputError(f"{path}: the plan figure's file name must end in .png")
    fig = plan_figure(world, plan, title)
    import matplotlib.pyplot as plt  # after plan_figure chose the Agg backend

    try:
        with atomic_path(path, suffix=".png") as tmp:
            # bbox_inches="tight" grows the canvas to whatever sticks out (legends, labels).
            fig.savefig(tmp, dpi=110, bbox_inches="tight", pad_inches=0.15)
    finally:
        plt.close(fig)
    return path


def plan_figure(world, plan, title: str):
    """The plan figure (matplotlib Figure; the caller closes it), as ``plot_plan`` draws it.

    Raises
    ------
    InputError
        If the plan's per-vertex arrays disagree in length.
    """
    xy = np.asarray(plan.xy_m, float).reshape(-1, 2)
    arrays = {k: np.asarray(getattr(plan, k), float) for k in
              ("t_s", "speed_mps", "energy_used_J", "energy_to_home_J", "reserve_J", "margin_J")}
    bad = [k for k, a in arrays.items() if a.shape != (len(xy),)]
    if bad:
        raise InputError(f"plan arrays {bad} do not have one value per tour vertex ({len(xy)})")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    layout = _layout(plt, world.true_map.boundary.bounds)
    try:
        _draw_plan_figure(layout, world, plan, xy, arrays, title)
    except BaseException:
        plt.close(layout.fig)
        raise
    return layout.fig


WIDE_MAP = 2.0
"""Maps wider than this (width / height) put the energy panel below the map, not beside it."""


@dataclass(frozen=True)
class _Layout:
    fig: object
    map_fig: object  # subfigure: map, colour bar, map legend
    energy_fig: object  # subfigure: energy panel and its legend
    map_w_in: float  # the map's drawn size [in]
    map_h_in: float
    wide: bool  # energy panel below the map (else beside it)


def _layout(plt, bounds) -> _Layout:
    """Figure and two subfigures (map, energy) sized to the map's shape.

    Each subfigure lays out its own axes, colour bar and legend (under it), so nothing
    overlaps or is clipped whatever the map's aspect ratio.
    """
    xmin, ymin, xmax, ymax = bounds
    aspect = (xmax - xmin) / max(ymax - ymin, 1e-9)
    if aspect > WIDE_MAP:  # a corridor along x: map on top, energy below
        map_w = 12.5
        map_h = max(map_w / aspect, 0.8)
        fig = plt.figure(figsize=(15.0, map_h + 8.5), layout="constrained")
        map_fig, energy_fig = fig.subfigures(2, 1, height_ratios=(map_h + 3.5, 5.0))
        return _Layout(fig, map_fig, energy_fig, map_w, map_h, wide=True)
    map_h = 6.8
    map_w = float(np.clip(map_h * aspect, 2.5, 9.5))
    map_h = min(map_h, map_w / aspect)
    left = map_w + 2.2  # y label, colour bar
    fig = plt.figure(figsize=(left + 6.8, 9.0), layout="constrained")
    map_fig, energy_fig = fig.subfigures(1, 2, width_ratios=(left, 6.8))
    return _Layout(fig, map_fig, energy_fig, map_w, map_h, wide=False)


def _draw_plan_figure(layout: _Layout, world, plan, xy, a: dict, title: str) -> None:
    from matplotlib.collections import LineCollection
    from matplotlib.colors import Normalize, to_rgb
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    ax = layout.map_fig.subplots()
    ex = layout.energy_fig.subplots()
    handles = draw_map(ax, world)

    covered = plan.covered
    if covered is not None and not covered.is_empty:
        xmin, ymin, xmax, ymax = world.true_map.boundary.bounds
        # Simplify far below a pixel so huge buffered tours draw fast.
        fine = shapely.simplify(covered, 2e-4 * max(xmax - xmin, ymax - ymin))
        ax.add_patch(_patch(fine, facecolor=(*to_rgb(COVERED_COLOUR), 0.3),
                            edgecolor=COVERED_EDGE, lw=0.7, zorder=2.5))
        handles.append(Patch(facecolor=(*to_rgb(COVERED_COLOUR), 0.3), edgecolor=COVERED_EDGE,
                             label="covered (sensed) area"))

    speed = a["speed_mps"][:-1]  # the speed of the segment leaving each vertex
    if len(xy) >= 2:
        segments = np.stack([xy[:-1], xy[1:]], axis=1)
        lo, hi = float(np.nanmin(speed)), float(np.nanmax(speed))
        # A dark casing under the coloured line keeps every speed readable on any fill.
        ax.add_collection(LineCollection(segments, colors="black", linewidths=2.6, alpha=0.55,
                                         capstyle="round", joinstyle="round", zorder=5))
        if f"{lo:.2f}" == f"{hi:.2f}":  # one speed: a colour bar from it to itself says nothing
            colour = _cmap(TOUR_CMAP)(0.45)
            ax.add_collection(LineCollection(segments, colors=[colour], linewidths=1.6,
                                             capstyle="round", joinstyle="round", zorder=5.1))
            handles.append(Line2D([], [], color=colour, lw=1.8,
                                  label=f"tour ({lo:.2f} m/s throughout)"))
        else:
            tour = LineCollection(segments, cmap=TOUR_CMAP, norm=Normalize(lo, hi),
                                  linewidths=1.6, capstyle="round", joinstyle="round",
                                  zorder=5.1)
            tour.set_array(speed)
            ax.add_collection(tour)
            _speed_colourbar(layout, ax, tour)
            handles.append(Line2D([], [], color=_cmap(TOUR_CMAP)(0.45), lw=1.8,
                                  label="tour (colour = speed)"))

    handles += _draw_continuation(ax, plan)
    wps = np.asarray(plan.waypoints_xy_m, float).reshape(-1, 2)
    if len(wps):
        ax.plot(wps[:, 0], wps[:, 1], ls="", marker="o", ms=4.5, color="white", mec="black",
                mew=0.8, zorder=6)
        _number_waypoints(ax, wps, _points_per_m(layout, world.map.boundary.bounds))
        handles.append(Line2D([], [], ls="", marker="o", ms=5, color="white", mec="black",
                              label="waypoint (visiting order)"))
    if len(xy) and np.hypot(*(xy[0] - np.asarray(world.home_xy_m, float))) > 1e-6:
        ax.plot(*xy[0], marker="o", ms=9, color="limegreen", mec="black", ls="", zorder=7)
        handles.append(Line2D([], [], marker="o", ms=8, color="limegreen", mec="black", ls="",
                              label="start"))
    # Legends under their panels, outside the axes: they never hide the tour.
    layout.map_fig.legend(handles=handles, loc="outside lower center",
                          ncol=3 if layout.wide or layout.map_w_in > 5 else 2, fontsize=8,
                          frameon=False)

    _draw_energy(ex, plan, a)
    layout.energy_fig.legend(loc="outside lower center", ncol=3, fontsize=8, frameon=False)
    # Title and headline span the figure: a narrow map's panel could not hold them.
    layout.fig.suptitle(f"{title}\n{_headline(world, plan, a)}", fontsize=10.5)


def _points_per_m(layout: _Layout, bounds) -> float:
    """Typographic points per map metre on the drawn map (equal axes) [pt/m]."""
    xmin, ymin, xmax, ymax = bounds
    return 72.0 * min(layout.map_w_in / max(xmax - xmin, 1e-9),
                      layout.map_h_in / max(ymax - ymin, 1e-9))


def _label_size(wps: np.ndarray, points_per_m: float, room: float = 1.0) -> float:
    """Type size [pt] of the waypoints' numbers: a number about as wide as ``room`` times
    the gap to the nearest other waypoint (at the tenth percentile: a few close pairs may
    touch), within ``WAYPOINT_LABEL_PT``."""
    smallest, largest = WAYPOINT_LABEL_PT
    if len(wps) < 2:
        return largest
    from scipy.spatial import cKDTree

    gap_pt = cKDTree(wps).query(wps, k=2)[0][:, 1] * points_per_m
    digits = len(str(len(wps) - 1))
    width_per_pt = 0.6 * digits + 0.4  # a digit is about 0.6 em wide; the offset and halo
    return float(np.clip(room * np.percentile(gap_pt, 10) / width_per_pt, smallest, largest))


def _number_waypoints(ax, wps: np.ndarray, points_per_m: float) -> None:
    """Every waypoint's visiting order beside it, in a white halo (legible on any fill
    without a box hiding the tour). Where the numbers would need type below the smallest
    size, they alternate above and below their waypoints: consecutive waypoints are the
    close ones along a lane, so each number gets about twice the room."""
    from matplotlib import patheffects

    size = _label_size(wps, points_per_m)
    stagger = size <= WAYPOINT_LABEL_PT[0]
    if stagger:
        size = _label_size(wps, points_per_m, room=2.0)
    halo = [patheffects.withStroke(linewidth=1.6, foreground="white")]
    for i, (x, y) in enumerate(wps):
        below = stagger and i % 2 == 1
        label = ax.annotate(str(i), (x, y), xytext=(2, -2 if below else 2),
                            textcoords="offset points", va="top" if below else "baseline",
                            fontsize=size, zorder=6.5, path_effects=halo, gid="waypoint-number")
        label.set_in_layout(False)  # inside the map: hundreds of them need not be laid out


def _speed_colourbar(layout: _Layout, ax, tour) -> None:
    """Colour bar sized in inches: 0.2 in thick, along the map's long side (its height
    beside a square or tall map, half its width under a wide one)."""
    if layout.wide:
        length = 0.5 * layout.map_w_in
        layout.map_fig.colorbar(tour, ax=ax, location="bottom", shrink=0.5,
                                aspect=length / 0.2, label="speed [m/s]")
    else:
        length = 0.85 * layout.map_h_in
        layout.map_fig.colorbar(tour, ax=ax, shrink=0.85, aspect=length / 0.2,
                                fraction=0.6 / layout.map_w_in, pad=0.12 / layout.map_w_in,
                                label="speed [m/s]")


def _cmap(name: str):
    import matplotlib

    return matplotlib.colormaps[name]


def _draw_energy(ex, plan, a: dict) -> None:
    """Energy used, to home, reserve and margin against mission time [kJ vs min]."""
    t_min = a["t_s"] / 60.0
    kJ = {k: v / 1e3 for k, v in a.items() if k.endswith("_J")}
    available = plan.summary.get("energy_available_J")
    dot = {"marker": "o", "ms": 5} if len(t_min) == 1 else {}  # a one-vertex plan: points
    ex.plot(t_min, kJ["energy_used_J"], color="tab:blue", lw=1.8, label="energy used", **dot)
    ex.plot(t_min, kJ["energy_to_home_J"], color="tab:orange", lw=1.5, label="energy to home",
            **dot)
    ex.plot(t_min, kJ["reserve_J"], color="tab:purple", lw=1.3, ls="-.", label="reserve", **dot)
    ex.plot(t_min, kJ["margin_J"], color="tab:green", lw=1.8, label="homing margin", **dot)
    committed = kJ["energy_used_J"] + kJ["energy_to_home_J"] + kJ["reserve_J"]
    ex.plot(t_min, committed, color="0.25", lw=1.0, ls=":", label="used + to home + reserve",
            **dot)
    if available is not None:
        ex.axhline(available / 1e3, color="tab:red", ls="--", lw=1.3,
                   label=f"available {available / 1e3:.4g} kJ")
    if len(t_min):
        i = int(np.nanargmin(kJ["margin_J"]))
        ex.plot(t_min[i], kJ["margin_J"][i], marker="v", color="tab:green", mec="black",
                ls="", zorder=5, clip_on=False)
        # Keep the label inside the panel: anchor it away from the nearer side.
        frac = (t_min[i] - t_min[0]) / max(t_min[-1] - t_min[0], 1e-12)
        ha, dx = ("right", -6) if frac > 0.7 else (("left", 6) if frac < 0.3 else ("center", 0))
        ex.annotate(f"min margin {kJ['margin_J'][i]:.3g} kJ\nat {t_min[i]:.1f} min",
                    (t_min[i], kJ["margin_J"][i]), xytext=(dx, 10), textcoords="offset points",
                    ha=ha, va="bottom", fontsize=8, color="darkgreen", zorder=6,
                    bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none",
                          "alpha": 0.8})
        ex.set_xlim(t_min[0], t_min[-1] if t_min[-1] > t_min[0] else t_min[0] + 1)
    ex.set_ylim(bottom=0)
    ex.set_xlabel("mission time [min]")
    ex.set_ylabel("energy [kJ]")
    ex.set_title("energy budget along the tour", fontsize=10)
    ex.grid(alpha=0.3)


def _draw_continuation(ax, plan) -> list:
    """The closed loop's route beyond the guaranteed tour: the part it is expected to fly
    before turning home (dashed), the turn point of the guaranteed tour and the expected one;
    returns legend handles (none for a plan without a continuation)."""
    from matplotlib.lines import Line2D

    rest = getattr(plan, "continuation_xy_m", None)
    expected = plan.expected_continuation_xy_m() if rest is not None else None
    if rest is None or len(rest) < 2:
        return []
    handles = []
    ax.plot(*rest[0], marker="D", ms=7, color="white", mec="black", ls="", zorder=7)
    handles.append(Line2D([], [], marker="D", ms=6, color="white", mec="black", ls="",
                          label="guaranteed tour turns home"))
    if expected is not None and len(expected) >= 2:
        ax.plot(expected[:, 0], expected[:, 1], ls=(0, (3, 2)), lw=1.6, color=CONTINUATION,
                zorder=5.2)
        ax.plot(*expected[-1], marker="X", ms=8, color=CONTINUATION, mec="black", ls="",
                zorder=7)
        handles += [Line2D([], [], ls=(0, (3, 2)), lw=1.6, color=CONTINUATION,
                           label="closed loop: expected extra route"),
                    Line2D([], [], marker="X", ms=7, color=CONTINUATION, mec="black", ls="",
                           label="closed loop: expected turn home")]
    return handles


def _headline(world, plan, a: dict) -> str:
    """Coverage, energy, duration and return probability in one line."""
    s = plan.summary
    covered = plan.covered
    cov = s.get("coverage_m2", covered.area if covered is not None else 0.0)
    frac = s.get("coverage_fraction")
    if frac is None:
        free = world.true_map.free_space.area
        frac = cov / free if free > 0 else float("nan")
    planned = s.get("energy_planned_J", a["energy_used_J"][-1] if len(a["energy_used_J"])
                    else float("nan"))
    available = s.get("energy_available_J")
    duration = s.get("duration_s", a["t_s"][-1] - a["t_s"][0] if len(a["t_s"]) else 0.0)
    p = s.get("return_probability")
    energy = (f"energy planned / available {planned / 1e3:.4g} / {available / 1e3:.4g} kJ "
              f"({100 * planned / available:.0f} %)" if available else
              f"energy planned {planned / 1e3:.4g} kJ")
    line2 = f"{energy}   ·   duration {duration / 60:.1f} min"
    if p is not None:
        line2 += f"   ·   return probability {p:.4g}"
    closed = s.get("closed_loop_coverage_m2")
    extra = f" guaranteed, {_area(closed)} expected in closed loop" if closed else ""
    return f"coverage {_area(cov)}{extra} ({100 * frac:.1f} % of the free area)   ·   {line2}"


def _area(m2: float) -> str:
    return f"{m2:,.0f} m²" if m2 >= 100 else f"{m2:.3g} m²"
