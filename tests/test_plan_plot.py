"""The plan figure: PNG written atomically, map drawing reusable and fast."""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, Point, box

from orange_plan.errors import InputError
from orange_plan.planning.plan import Plan
from orange_plan.viz import plan_plot
from orange_plan.viz.plan_plot import draw_map, plot_plan
from orange_plan.world.geomap import Map, Surface
from orange_plan.world.raster import ElevationRaster
from orange_plan.world.terrain import World

REPO = Path(__file__).resolve().parents[1]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def lawnmower(world, region, spacing_m: float, step_m: float) -> np.ndarray:
    """Home -> boustrophedon rows over the free part of ``region`` -> home, vertices every
    ``step_m`` (row changes may cut corners: this is a picture, not a planner)."""
    free = world.map.free_space.intersection(region)
    x0, y0, x1, y1 = free.bounds
    pts = [np.asarray(world.home_xy_m, float)]
    for k, y in enumerate(np.arange(y0 + spacing_m / 2, y1, spacing_m)):
        row = free.intersection(LineString([(x0, y), (x1, y)]))
        parts = sorted((g for g in getattr(row, "geoms", [row]) if g.length > 0),
                       key=lambda g: g.bounds[0])
        for part in parts if k % 2 == 0 else parts[::-1]:
            a, b = np.asarray(part.coords)[[0, -1]]
            if k % 2:
                a, b = (a, b) if a[0] > b[0] else (b, a)
            else:
                a, b = (a, b) if a[0] < b[0] else (b, a)
            n = max(2, int(np.ceil(np.hypot(*(b - a)) / step_m)) + 1)
            pts.extend(np.linspace(a, b, n))
    pts.append(np.asarray(world.home_xy_m, float))
    return np.asarray(pts)


def synthetic_plan(world, xy: np.ndarray, sensor_radius_m: float, n_waypoints: int = 12,
                   available_J: float | None = None) -> Plan:
    """A Plan with plausible monotone energies along ``xy`` (not a planner's output)."""
    seg = np.hypot(*np.diff(xy, axis=0).T)
    dist = np.concatenate([[0.0], np.cumsum(seg)])
    speed = 0.8 + 0.6 * (0.5 + 0.5 * np.sin(dist / max(dist[-1], 1) * 9.0))
    t = np.concatenate([[0.0], np.cumsum(seg / speed[:-1] / 0.9)])
    used = 40.0 * dist + 8.0 * t
    to_home = 45.0 * np.hypot(*(xy - np.asarray(world.home_xy_m)).T)
    available = available_J or 1.15 * float(np.max(used + to_home)) + 5e3
    reserve = np.full(len(xy), 0.1 * available)
    margin = np.maximum(available - used - to_home - reserve, 0.0)
    covered = shapely.buffer(LineString(xy), sensor_radius_m).intersection(world.map.free_space)
    wp_idx = np.linspace(1, len(xy) - 2, n_waypoints).astype(int) if n_waypoints else []
    free_area = world.map.free_space.area
    return Plan(
        xy_m=xy, t_s=t, speed_mps=speed, energy_used_J=used, energy_to_home_J=to_home,
        reserve_J=reserve, margin_J=margin, waypoints_xy_m=xy[wp_idx].reshape(-1, 2),
        covered=covered,
        summary={"energy_available_J": available, "energy_planned_J": float(used[-1]),
                 "reserve_J": float(reserve[0]), "coverage_m2": covered.area,
                 "coverage_fraction": covered.area / free_area,
                 "coverage_bound_m2": free_area, "duration_s": float(t[-1]),
                 "return_probability": 0.99, "planner_seconds": 1.0},
    )


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC
    width, height = struct.unpack(">II", data[16:24])
    return width, height


@pytest.fixture(scope="module")
def campus():
    from orange_plan.context import load_context

    return load_context(REPO / "scenarios" / "kiwibot_campus.toml")


def campus_plan(ctx, n_waypoints=12):
    world = ctx.world
    hx, hy = world.home_xy_m
    xy = lawnmower(world, box(hx - 40, hy - 250, hx + 560, hy + 250), 40.0, 10.0)
    return synthetic_plan(world, xy, 8.0, n_waypoints=n_waypoints)


def test_plan_png_written_for_campus(campus, tmp_path):
    out = tmp_path / "figs" / "plan.png"
    assert plot_plan(campus.world, campus_plan(campus), out, "kiwibot_campus") == out
    width, height = png_size(out)
    assert 1000 <= width <= 3000 and 500 <= height <= 2000
    assert sorted(os.listdir(out.parent)) == ["plan.png"]  # no temporary file left


@pytest.mark.parametrize("scenario", ["marine_survey", "husky_a200"])
def test_plan_png_other_scenarios(scenario, tmp_path):
    from orange_plan.context import load_context

    ctx = load_context(REPO / "scenarios" / f"{scenario}.toml")
    x0, y0, x1, y1 = ctx.world.map.boundary.bounds
    region = box(x0, y0, x0 + 0.7 * (x1 - x0), y0 + 0.7 * (y1 - y0))
    step = (x1 - x0) / 100
    xy = lawnmower(ctx.world, region, 8 * step, step)
    plan = synthetic_plan(ctx.world, xy, 2 * step, n_waypoints=60)
    out = plot_plan(ctx.world, plan, tmp_path / f"{scenario}.png", scenario)
    assert out == tmp_path / f"{scenario}.png"
    width, height = png_size(out)
    assert 1000 <= width <= 3000 and 500 <= height <= 2000
    assert os.listdir(tmp_path) == [f"{scenario}.png"]  # no temporary file left


def test_bad_suffix_writes_nothing(campus, tmp_path):
    with pytest.raises(InputError, match=r"\.png"):
        plot_plan(campus.world, campus_plan(campus), tmp_path / "plan.jpg", "x")
    assert os.listdir(tmp_path) == []


def test_mismatched_arrays_refused(campus, tmp_path):
    plan = campus_plan(campus)
    bad = Plan(**{**plan.__dict__, "speed_mps": plan.speed_mps[:-1]})
    with pytest.raises(InputError, match="speed_mps"):
        plot_plan(campus.world, bad, tmp_path / "plan.png", "x")
    assert os.listdir(tmp_path) == []


def test_failure_mid_draw_keeps_old_file_and_leaves_no_temporary(campus, tmp_path, monkeypatch):
    out = tmp_path / "plan.png"
    out.write_bytes(b"old")

    def boom(*args, **kwargs):
        raise RuntimeError("boom while drawing")

    monkeypatch.setattr(plan_plot, "_draw_energy", boom)
    with pytest.raises(RuntimeError, match="boom"):
        plot_plan(campus.world, campus_plan(campus), out, "x")
    assert out.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["plan.png"]


def test_failure_while_saving_leaves_no_temporary(campus, tmp_path, monkeypatch):
    import matplotlib.figure

    def half_write(self, fname, **kwargs):
        Path(fname).write_bytes(PNG_MAGIC + b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", half_write)
    with pytest.raises(OSError, match="disk full"):
        plot_plan(campus.world, campus_plan(campus), tmp_path / "plan.png", "x")
    assert os.listdir(tmp_path) == []


def bare_world(elevation=None, surfaces=(), obstacles=(), no_go=(), size=50.0) -> World:
    m = Map(boundary=box(0, 0, size, size), obstacles=tuple(obstacles), no_go=tuple(no_go),
            surfaces=tuple(surfaces), home_xy_m=(1.0, 1.0), default_surface=None,
            elevation=elevation, path=Path("bare.geojson"))
    return World(m, 0.03, "default", (1.0, 1.0))


def test_draw_map_without_surfaces_or_dem():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    world = bare_world()
    fig, ax = plt.subplots()
    try:
        handles = draw_map(ax, world)
        assert [h.get_label() for h in handles] == ["home"]
        assert ax.get_xlim()[0] < 0 < 50 < ax.get_xlim()[1]
        assert ax.get_aspect() == 1.0
        # A bare Map (no World) draws too, with the map's own home; or without a home.
        ax.clear()
        assert [h.get_label() for h in draw_map(ax, world.map)] == ["home"]
        ax.clear()
        assert draw_map(ax, world.map, home=False) == []
    finally:
        plt.close(fig)


def test_draw_map_flat_dem_and_legend_entries():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    flat = ElevationRaster(np.zeros((30, 30)), 1.0, 1.0, 2.0)
    world = bare_world(
        elevation=flat,
        surfaces=[Surface("grass", 0.08, box(0, 0, 20, 50)),
                  Surface("grass", 0.1, box(30, 0, 40, 50))],
        obstacles=[box(22, 22, 26, 26)], no_go=[box(40, 40, 48, 48)])
    fig, ax = plt.subplots()
    try:
        labels = [h.get_label() for h in draw_map(ax, world)]
    finally:
        plt.close(fig)
    assert labels == ["default ground, crr 0.03", "grass, crr 0.08/0.1", "obstacle",
                      "no-go zone", "home"]
    fig, ax = plt.subplots()
    try:  # a bare Map has no robot crr to name for the ground between surfaces
        labels = [h.get_label() for h in draw_map(ax, world.map, home=False)]
    finally:
        plt.close(fig)
    assert labels[:2] == ["elsewhere: the robot's crr", "grass, crr 0.08/0.1"]


def artist_count(fig) -> int:
    """Every artist drawn on the figure's axes (lines, collections, patches, texts...)."""
    return sum(len(ax.get_children()) for ax in fig.get_axes())


def test_big_map_draws_with_as_many_artists_for_5000_vertices_as_for_500(tmp_path):
    """A 2 km map with a DEM, obstacles and surfaces draws; the tour is drawn as whole
    collections, never one artist per vertex: the same plan resampled from 500 to 5000 vertices
    (the same 200 waypoints) adds no artist. (How long drawing takes is a benchmark's
    business, not a test's.)"""
    import matplotlib.pyplot as plt

    n = 401
    g = np.linspace(-5.0, 2005.0, n)
    gx, gy = np.meshgrid(g, g)
    z = 30 * np.exp(-((gx - 1200) ** 2 + (gy - 900) ** 2) / (2 * 300.0**2)) + 0.004 * gx
    dem = ElevationRaster(z, -5.0, -5.0, float(g[1] - g[0]))
    obstacles = [Point(x, y).buffer(25) for x in (400, 900, 1500) for y in (500, 1300)]
    world = bare_world(elevation=dem, size=2000.0, obstacles=obstacles,
                       surfaces=[Surface("gravel", 0.05, box(0, 0, 800, 2000)),
                                 Surface("grass", 0.09, box(1300, 200, 2000, 1600))],
                       no_go=[box(1700, 1700, 1950, 1950)])
    lanes = lawnmower(world, box(0, 0, 2000, 2000), 100.0, 10.0)
    assert len(lanes) > 3000
    counts = []
    for n_vertices in (500, 5000):
        idx = np.linspace(0, len(lanes) - 1, n_vertices)
        xy = np.stack([np.interp(idx, np.arange(len(lanes)), lanes[:, k]) for k in (0, 1)],
                      axis=1)
        plan = synthetic_plan(world, xy, 20.0, n_waypoints=200)
        fig = plan_plot.plan_figure(world, plan, f"2 km map, {n_vertices} vertices")
        counts.append(artist_count(fig))
        plt.close(fig)
    assert counts[0] == counts[1]
    plot_plan(world, plan, tmp_path / "big.png", "2 km map, 5000 vertices")
    png_size(tmp_path / "big.png")


def test_start_away_from_home_sparse_summary_and_single_vertex(campus, tmp_path):
    """A replanned tour starts where the robot is; summaries may lack keys; a plan that
    cannot leave home is one vertex. All draw."""
    plan = campus_plan(campus, n_waypoints=0)
    mid = Plan(**{**plan.__dict__, **{k: getattr(plan, k)[5:] for k in
                                      ("xy_m", "t_s", "speed_mps", "energy_used_J",
                                       "energy_to_home_J", "reserve_J", "margin_J")},
                  "summary": {}})
    png_size(plot_plan(campus.world, mid, tmp_path / "mid.png", "from mid-mission"))
    home = np.asarray([campus.world.home_xy_m])
    stay = Plan(xy_m=home, t_s=np.zeros(1), speed_mps=np.ones(1), energy_used_J=np.zeros(1),
                energy_to_home_J=np.zeros(1), reserve_J=np.full(1, 1e4),
                margin_J=np.full(1, 2e5), waypoints_xy_m=np.zeros((0, 2)), covered=None,
                summary={"energy_available_J": 2.1e5, "return_probability": 1.0})
    png_size(plot_plan(campus.world, stay, tmp_path / "stay.png", "nothing to do"))
    assert sorted(os.listdir(tmp_path)) == ["mid.png", "stay.png"]


def test_draw_map_surface_outlines_for_overlay_figures(campus, tmp_path):
    """A figure with its own field image (like the reach figure) asks for outlines: no fill
    then hides the image, and the legend shows outlined surfaces."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from orange_plan.atomic import save_figure

    fig, ax = plt.subplots(figsize=(8, 5.5), layout="constrained")
    handles = draw_map(ax, campus.world, surfaces="outline")
    labels = [h.get_label() for h in handles]
    assert not any("(default)" in label for label in labels)  # no default-ground fill
    assert "asphalt, crr 0.015" in labels
    filled = [p for p in ax.patches if p.get_zorder() < 2 and p.get_facecolor()[3] > 0]
    assert filled == []
    gx, gy = np.meshgrid(np.linspace(0, 800, 80), np.linspace(0, 800, 80))
    ax.imshow(np.hypot(gx - 60, gy - 400), origin="lower", extent=(0, 800, 0, 800),
              cmap="viridis", alpha=0.8, zorder=2)
    fig.legend(handles=handles, loc="outside right upper", fontsize=7)
    png_size(save_figure(fig, tmp_path / "overlay.png"))
    with pytest.raises(ValueError, match="outline"):
        draw_map(plt.figure().add_subplot(), campus.world, surfaces="hatch")
    plt.close("all")


def waypoint_numbers(fig) -> list:
    return [t for t in fig.findobj(lambda a: a.get_gid() == "waypoint-number")]


@pytest.mark.parametrize("n_waypoints", [12, 150, 400])
def test_every_waypoint_is_numbered_legibly(campus, n_waypoints):
    """Every waypoint carries its visiting order, however many there are, in type no
    smaller than WAYPOINT_LABEL_PT allows, and few numbers run into each other."""
    import matplotlib.pyplot as plt

    fig = plan_plot.plan_figure(campus.world, campus_plan(campus, n_waypoints), "campus")
    try:
        labels = waypoint_numbers(fig)
        assert [t.get_text() for t in labels] == [str(i) for i in range(n_waypoints)]
        assert min(t.get_fontsize() for t in labels) >= plan_plot.WAYPOINT_LABEL_PT[0]
        renderer = fig.canvas.get_renderer()
        boxes = [t.get_window_extent(renderer) for t in labels]
        touching = sum(any(a.overlaps(b) for b in boxes[:i] + boxes[i + 1:])
                       for i, a in enumerate(boxes))
        assert touching <= 0.1 * n_waypoints, touching
    finally:
        plt.close(fig)


def test_one_speed_is_said_in_the_legend_without_a_colour_bar(campus):
    import matplotlib.pyplot as plt

    plan = campus_plan(campus)
    steady = Plan(**{**plan.__dict__, "speed_mps": np.full(len(plan.xy_m), 1.25)})
    for which, expect_bar in ((plan, True), (steady, False)):
        fig = plan_plot.plan_figure(campus.world, which, "campus")
        try:
            bars = [ax for ax in fig.findobj(lambda a: hasattr(a, "_colorbar"))]
            from matplotlib.text import Text

            texts = [t.get_text() for t in fig.findobj(Text)]
            assert bool(bars) is expect_bar
            assert any("1.25 m/s throughout" in t for t in texts) is not expect_bar
        finally:
            plt.close(fig)
