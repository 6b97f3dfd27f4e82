"""Small worlds for the planning tests: a rectangle with boxes, an optional surface and a hill.

``write_world(tmp_path, ...)`` writes the map, an ESRI ASCII DEM (if a hill or ramp is asked
for) and a scenario TOML, and returns the scenario path.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import tomli_w

DEM_CELL_M = 2.0


def box(x0, y0, x1, y1):
    return [[[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]]


def write_world(folder: Path, width_m=40.0, height_m=30.0, obstacles=(), surfaces=(),
                hill=None, ramp=0.0, home=(2.0, 2.0), rated_energy_Wh=1.0,
                reserve=None, turn=0.0, drag=0.05, name="world", time_limit_s=None,
                wind=(0.0, 0.0), terms=(), radius_m=None, clearance_m=None) -> Path:
    """Write map + DEM + scenario; ``hill`` = (cx, cy, height_m, sigma_m), ``ramp`` = dz/dx,
    ``wind`` = (speed_mps, from_deg), ``terms`` = extra model terms, ``radius_m`` and
    ``clearance_m`` the robot's keep-away (left out: the defaults, 0)."""
    features = [
        {"type": "Feature", "properties": {"kind": "boundary"},
         "geometry": {"type": "Polygon", "coordinates": box(0, 0, width_m, height_m)}},
        {"type": "Feature", "properties": {"kind": "home"},
         "geometry": {"type": "Point", "coordinates": list(home)}},
    ]
    for i, (x0, y0, x1, y1, crr) in enumerate(surfaces):
        features.append({"type": "Feature",
                         "properties": {"kind": "surface", "name": f"s{i}", "crr": crr},
                         "geometry": {"type": "Polygon", "coordinates": box(x0, y0, x1, y1)}})
    for x0, y0, x1, y1 in obstacles:
        features.append({"type": "Feature", "properties": {"kind": "obstacle"},
                         "geometry": {"type": "Polygon", "coordinates": box(x0, y0, x1, y1)}})
    top = {}
    if hill is not None or ramp:
        top["elevation"] = f"{name}_dem.asc"
        write_dem(folder / top["elevation"], width_m, height_m, hill, ramp)
    (folder / f"{name}.geojson").write_text(
        json.dumps({"type": "FeatureCollection", **top, "features": features}), encoding="utf-8")
    scenario = {
        "name": name,
        "map": f"{name}.geojson",
        "robot": {"kind": "ground", "mass_kg": 20.0, "crr": 0.03, "drag_coeff_kg_per_m": drag,
                  "v_min_mps": 0.2, "v_max_mps": 1.5, "accel_max_mps2": 0.5,
                  "turn_coeff_W_s_per_rad": turn},
        "losses": {"battery": 0.05, "motor": 0.2, "mechanical": 0.1, "ancillary": 0.1},
        "battery": {"rated_energy_Wh": rated_energy_Wh},
        "ancillary": {"s0_W": 2.0, "s1_W_per_Hz": 0.0, "sensor_rate_Hz": 0.0,
                      "compute_W": 2.0, "comm_W": 1.0},
        "mission": {"duty_cycle": 0.9, "sensor_radius_m": 1.0,
                    "reserve": reserve or {"fraction": 0.1}},
        "environment": {"wind_speed_mps": wind[0], "wind_from_deg": wind[1]},
    }
    if terms:
        scenario["model"] = {"terms": list(terms)}
    if time_limit_s is not None:
        scenario["mission"]["time_limit_s"] = time_limit_s
    if radius_m is not None:
        scenario["robot"]["radius_m"] = radius_m
    if clearance_m is not None:
        scenario["mission"]["clearance_m"] = clearance_m
    path = folder / f"{name}.toml"
    path.write_text(tomli_w.dumps(scenario), encoding="utf-8")
    return path


def draw_world_spec(draw, width_cells=(15, 25), height_cells=(10, 20), box_cells=(4, 6),
                    hill_height_m=8.0, ramp_max=0.15, surface_width_m=10.0) -> dict:
    """A random ``write_world`` spec inside a hypothesis ``@composite``: a rectangle on a 2 m
    lattice, up to three boxes, a hill, a ramp or flat ground, and one slow surface strip."""
    from hypothesis import strategies as st

    w = draw(st.integers(*width_cells)) * 2.0
    h = draw(st.integers(*height_cells)) * 2.0
    boxes = []
    for _ in range(draw(st.integers(0, 3))):
        x0 = draw(st.integers(3, int(w / 2) - 2)) * 2.0
        y0 = draw(st.integers(0, int(h / 2) - 2)) * 2.0
        bw = draw(st.integers(1, box_cells[0])) * 2.0
        bh = draw(st.integers(1, box_cells[1])) * 2.0
        boxes.append((x0, y0, min(x0 + bw, w - 2), min(y0 + bh, h)))
    terrain = draw(st.sampled_from(["hill", "ramp", "flat"]))
    hill, ramp = None, 0.0
    if terrain == "hill":
        hill = (draw(st.floats(0, w)), draw(st.floats(0, h)), draw(st.floats(1, hill_height_m)),
                draw(st.floats(3, 10)))
    elif terrain == "ramp":
        ramp = draw(st.floats(-ramp_max, ramp_max))
    sx = draw(st.integers(0, int(w / 2) - 1)) * 2.0
    surfaces = [(sx, 0.0, sx + surface_width_m, h, draw(st.floats(0.02, 0.3)))]
    return dict(width_m=w, height_m=h, obstacles=boxes, hill=hill, ramp=ramp, surfaces=surfaces)


def write_dem(path: Path, width_m, height_m, hill, ramp) -> None:
    """ESRI ASCII grid covering the rectangle with a margin cell (centres every DEM_CELL_M)."""
    c = DEM_CELL_M
    xs = np.arange(-c, width_m + 2 * c, c)
    ys = np.arange(-c, height_m + 2 * c, c)
    gx, gy = np.meshgrid(xs, ys)
    z = ramp * gx
    if hill is not None:
        cx, cy, h, s = hill
        z = z + h * np.exp(-((gx - cx) ** 2 + (gy - cy) ** 2) / (2 * s * s))
    rows = z[::-1]  # file rows run north to south
    head = (f"ncols {len(xs)}\nnrows {len(ys)}\nxllcenter {xs[0]}\nyllcenter {ys[0]}\n"
            f"cellsize {c}\n")
    body = "\n".join(" ".join(f"{v:.6f}" for v in r) for r in rows)
    path.write_text(head + body + "\n", encoding="utf-8")
