"""Generated benchmark worlds: a seeded random family and one large map (written, not shipped).

``random_scenario(folder, seed)`` writes a rectangle with random box and polygon obstacles,
optionally a DEM of Gaussian hills (ESRI ASCII grid) and a wind, plus a scenario for a
Kiwibot-class delivery robot whose battery covers about half the free area (so coverage is
energy-limited). ``large_scenario(folder)`` writes the 2 km x 2 km map with 300 obstacles and a
DEM of the planning-time target. Same seed, same files.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import shapely
import tomli_w

HOME_CLEARANCE_M = 8.0
"""No obstacle comes closer than this to home [m]."""


def _box(x0, y0, x1, y1) -> list:
    return [[[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]]


def _feature(kind: str, geom_type: str, coordinates, **props) -> dict:
    return {"type": "Feature", "properties": {"kind": kind, **props},
            "geometry": {"type": geom_type, "coordinates": coordinates}}


def random_obstacles(rng, width_m: float, height_m: float, n: int, home_xy,
                     size_m=(8.0, 40.0), polygon_share: float = 0.5) -> list:
    """``n`` obstacles (boxes and convex polygons) inside the rectangle, clear of home.

    Obstacles may overlap (the map's keep-out is their union); one that would come within
    ``HOME_CLEARANCE_M`` of home is drawn again.
    """
    home = shapely.Point(home_xy).buffer(HOME_CLEARANCE_M)
    out = []
    margin = 2.0
    while len(out) < n:
        w, h = rng.uniform(*size_m, 2)
        x0 = rng.uniform(margin, width_m - margin - w)
        y0 = rng.uniform(margin, height_m - margin - h)
        if rng.uniform() < polygon_share:
            pts = rng.uniform([x0, y0], [x0 + w, y0 + h], (7, 2))
            geom = shapely.MultiPoint(pts).convex_hull
        else:
            geom = shapely.box(x0, y0, x0 + w, y0 + h)
        if geom.geom_type != "Polygon" or geom.area < 1.0 or geom.intersects(home):
            continue
        out.append(geom)
    return out


def write_hills_dem(path: Path, width_m: float, height_m: float, hills, cell_m: float) -> None:
    """ESRI ASCII grid of Gaussian hills ``(cx, cy, height_m, sigma_m)`` covering the
    rectangle with one margin cell (values at cell centres)."""
    xs = np.arange(-cell_m, width_m + 2 * cell_m, cell_m)
    ys = np.arange(-cell_m, height_m + 2 * cell_m, cell_m)
    gx, gy = np.meshgrid(xs, ys)
    z = np.zeros_like(gx)
    for cx, cy, h, s in hills:
        z += h * np.exp(-((gx - cx) ** 2 + (gy - cy) ** 2) / (2 * s * s))
    head = (f"ncols {len(xs)}\nnrows {len(ys)}\nxllcenter {xs[0]}\nyllcenter {ys[0]}\n"
            f"cellsize {cell_m}\n")
    body = "\n".join(" ".join(f"{v:.3f}" for v in row) for row in z[::-1])
    path.write_text(head + body + "\n", encoding="utf-8")


def _robot_scenario(name: str, map_file: str, rated_energy_Wh: float, sensor_radius_m: float,
                    wind_mps: float, wind_from_deg: float, time_limit_s=None) -> dict:
    """A Kiwibot-class ground robot (the numbers of scenarios/kiwibot_campus.toml)."""
    mission = {"duty_cycle": 0.9, "sensor_radius_m": sensor_radius_m,
               "reserve": {"confidence": 0.95}}
    if time_limit_s is not None:
        mission["time_limit_s"] = time_limit_s
    return {
        "name": name,
        "map": map_file,
        "robot": {"kind": "ground", "mass_kg": 25.0, "crr": 0.02, "drag_coeff_kg_per_m": 0.15,
                  "v_min_mps": 0.3, "v_max_mps": 1.2, "accel_max_mps2": 0.5, "hover_W": 0.0,
                  "turn_coeff_W_s_per_rad": 0.0},
        "losses": {"battery": 0.03, "motor": 0.20, "mechanical": 0.10, "ancillary": 0.06},
        "battery": {"rated_energy_Wh": rated_energy_Wh, "cycles": 0, "age_days": 0},
        "ancillary": {"s0_W": 3.0, "s1_W_per_Hz": 0.05, "sensor_rate_Hz": 10.0,
                      "compute_W": 10.0, "comm_W": 2.5},
        "mission": mission,
        "environment": {"wind_speed_mps": wind_mps, "wind_from_deg": wind_from_deg,
                        "ambient_C": 20.0},
    }


def write_world(folder: Path, name: str, width_m: float, height_m: float, obstacles,
                home_xy, hills=(), dem_cell_m: float = 5.0, rated_energy_Wh: float = 50.0,
                sensor_radius_m: float = 4.0, wind=(0.0, 0.0), time_limit_s=None) -> Path:
    """Write ``NAME.geojson`` (+ ``NAME_dem.asc`` with hills) and ``NAME.toml``; return the
    scenario path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    features = [_feature("boundary", "Polygon", _box(0, 0, width_m, height_m)),
                _feature("home", "Point", list(map(float, home_xy)))]
    features += [_feature("obstacle", "Polygon", [np.round(np.asarray(g.exterior.coords), 3)
                                                   .tolist()]) for g in obstacles]
    top = {"default_surface": {"name": "asphalt", "crr": 0.015}}
    if hills:
        top["elevation"] = f"{name}_dem.asc"
        write_hills_dem(folder / top["elevation"], width_m, height_m, hills, dem_cell_m)
    (folder / f"{name}.geojson").write_text(
        json.dumps({"type": "FeatureCollection", **top, "features": features}), encoding="utf-8")
    scenario = _robot_scenario(name, f"{name}.geojson", rated_energy_Wh, sensor_radius_m,
                               wind[0], wind[1], time_limit_s)
    path = folder / f"{name}.toml"
    path.write_text(tomli_w.dumps(scenario), encoding="utf-8")
    return path


def random_scenario(folder, seed: int, width_m: float = 300.0, height_m: float = 200.0,
                    n_obstacles: int | None = None, sensor_radius_m: float = 4.0,
                    coverage_share: float = 0.5) -> Path:
    """One member of the random family (seeded): obstacles, maybe hills, maybe wind.

    The battery is sized so that a lawnmower at 2 r spacing on flat ground could sense about
    ``coverage_share`` of the free area (26 J/m for this robot at 1.2 m/s on asphalt).
    """
    rng = np.random.default_rng(1000 + int(seed))
    home = (10.0, height_m / 2)
    n = int(rng.integers(4, 13)) if n_obstacles is None else n_obstacles
    obstacles = random_obstacles(rng, width_m, height_m, n, home, (8.0, 0.2 * height_m))
    hills = ()
    if rng.uniform() < 0.5:
        hills = tuple((rng.uniform(0.2, 0.9) * width_m, rng.uniform(0.1, 0.9) * height_m,
                       rng.uniform(5.0, 20.0), rng.uniform(0.1, 0.25) * width_m)
                      for _ in range(int(rng.integers(1, 4))))
    wind = (0.0, 0.0)
    if rng.uniform() < 0.5:
        wind = (float(np.round(rng.uniform(1.0, 5.0), 1)), float(np.round(rng.uniform(0, 360))))
    free = width_m * height_m
    if obstacles:
        free -= shapely.union_all(obstacles).area
    distance_m = coverage_share * free / (2 * sensor_radius_m)
    wh = float(np.round(distance_m * 26.0 / 3600 / 0.97, 1))
    return write_world(folder, f"random_{seed}", width_m, height_m, obstacles, home, hills,
                       5.0, wh, sensor_radius_m, wind)


def large_scenario(folder, n_obstacles: int = 300, size_m: float = 2000.0) -> Path:
    """The planning-time map: 2 km x 2 km, 300 obstacles, a DEM of hills (10 m cells)."""
    rng = np.random.default_rng(2000)
    home = (50.0, size_m / 2)
    obstacles = random_obstacles(rng, size_m, size_m, n_obstacles, home, (10.0, 60.0))
    hills = tuple((rng.uniform(0.1, 0.9) * size_m, rng.uniform(0.1, 0.9) * size_m,
                   rng.uniform(10.0, 40.0), rng.uniform(100.0, 300.0)) for _ in range(6))
    return write_world(folder, "large_2km", size_m, size_m, obstacles, home, hills, 10.0,
                       250.0, 5.0, (2.0, 240.0), 3600.0)
