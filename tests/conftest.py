"""Shared fixtures: small valid maps and scenarios written into ``tmp_path``.

``write_scenario(tmp_path, set={"robot.mass_kg": -1}, drop=["robot.crr"])`` writes the base
scenario with one key changed or removed, so each bad-input test states only what is bad.
"""

from __future__ import annotations

import copy
import json
import os
from pathlib import Path

import pytest
import tomli_w

REPO = Path(__file__).resolve().parents[1]


def _one_blas_thread_per_worker() -> None:
    """pytest-xdist runs one worker per core; each worker's BLAS starting a thread per core
    as well oversubscribes the machine, and OpenBLAS's threads spin while they wait: on two
    cores the diagnosis tests took 6 min 19 s, against 1 min 30 s with one BLAS thread per
    worker. One thread, for the worker and for the processes it starts."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)  # BLAS already loaded in this worker


_one_blas_thread_per_worker()

# A 20 m x 10 m yard: grass on the east half, one box obstacle, home at (2, 5).
BOUNDARY = [[0, 0], [20, 0], [20, 10], [0, 10], [0, 0]]
GRASS = [[10, 0], [20, 0], [20, 10], [10, 10], [10, 0]]
BOX = [[4, 7], [6, 7], [6, 9], [4, 9], [4, 7]]
HOME = [2.0, 5.0]


def feature(kind: str, geom_type: str, coordinates, **props) -> dict:
    """One GeoJSON Feature with ``properties.kind``."""
    return {
        "type": "Feature",
        "properties": {"kind": kind, **props},
        "geometry": {"type": geom_type, "coordinates": coordinates},
    }


def base_features() -> list[dict]:
    return [
        feature("boundary", "Polygon", [BOUNDARY]),
        feature("surface", "Polygon", [GRASS], name="grass", crr=0.1),
        feature("obstacle", "Polygon", [BOX]),
        feature("home", "Point", HOME),
    ]


def write_map(folder: Path, features=None, name: str = "yard.geojson", **top) -> Path:
    """Write a FeatureCollection (default: the yard) with optional top-level members."""
    data = {"type": "FeatureCollection", **top,
            "features": base_features() if features is None else features}
    path = folder / name
    path.write_text(json.dumps(data), encoding="utf-8")
    return path


BASE_SCENARIO = {
    "name": "test_yard",
    "map": "yard.geojson",
    "robot": {
        "kind": "ground",
        "mass_kg": 10.0,
        "crr": 0.05,
        "drag_coeff_kg_per_m": 0.0,
        "v_min_mps": 0.2,
        "v_max_mps": 1.0,
    },
    "losses": {"battery": 0.1, "motor": 0.2, "mechanical": 0.1, "ancillary": 0.2},
    "battery": {"rated_energy_Wh": 10.0, "cycles": 100, "age_days": 50,
                "k1_per_cycle": 0.001, "k2_per_day": 0.002},
    "ancillary": {"s0_W": 2.0, "s1_W_per_Hz": 0.1, "sensor_rate_Hz": 10.0,
                  "compute_W": 3.0, "comm_W": 1.0},
    "mission": {"duty_cycle": 0.8, "sensor_radius_m": 1.0, "reserve": {"fraction": 0.1}},
    "environment": {"wind_speed_mps": 0.0, "wind_from_deg": 0.0},
}


def scenario_dict(set: dict | None = None, drop=()) -> dict:
    """The base scenario with dotted keys set (``{"robot.mass_kg": -1}``) or dropped."""
    data = copy.deepcopy(BASE_SCENARIO)
    for dotted, value in (set or {}).items():
        *parents, key = dotted.split(".")
        table = data
        for p in parents:
            table = table.setdefault(p, {})
        table[key] = value
    for dotted in drop:
        *parents, key = dotted.split(".")
        table = data
        for p in parents:
            table = table[p]
        del table[key]
    return data


def write_scenario(folder: Path, set: dict | None = None, drop=(), map_features=None,
                   name: str = "scenario.toml", **map_top) -> Path:
    """Write the yard map (unless already there) and the scenario with changes; return its path."""
    if map_features is not None or map_top or not (folder / "yard.geojson").exists():
        write_map(folder, map_features, **map_top)
    path = folder / name
    path.write_text(tomli_w.dumps(scenario_dict(set, drop)), encoding="utf-8")
    return path


@pytest.fixture
def map_path(tmp_path) -> Path:
    """A valid yard map in tmp_path."""
    return write_map(tmp_path)


@pytest.fixture
def scenario_path(tmp_path) -> Path:
    """A valid scenario (and its map) in tmp_path."""
    return write_scenario(tmp_path)


def write_asc(path: Path, z_rows_north_first, cell_m: float, x0: float, y0: float,
              corner: bool = True) -> Path:
    """Write an ESRI ASCII grid; ``corner`` picks xllcorner (else xllcenter)."""
    rows = [list(r) for r in z_rows_north_first]
    key = "corner" if corner else "center"
    head = (f"ncols {len(rows[0])}\nnrows {len(rows)}\nxll{key} {x0}\nyll{key} {y0}\n"
            f"cellsize {cell_m}\nNODATA_value -9999\n")
    body = "\n".join(" ".join(f"{v:.6f}" for v in r) for r in rows)
    path.write_text(head + body + "\n", encoding="utf-8")
    return path


def run_cli(*args: str):
    """Run ``orange-plan ARGS`` in-process; return (exit_code, stdout, stderr)."""
    from typer.testing import CliRunner

    from orange_plan.cli import _register_commands, app

    _register_commands()
    result = CliRunner().invoke(app, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


DATA = REPO.parent / "shared" / "data"
"""The real recordings (BorealTC, TUM BMW i3) the data tests read; absent on a fresh clone."""
DATA_SKIP = ("shared/data", "real data")
"""Words of a skip reason that mean "the real recordings are not here"."""


def data_skips(terminalreporter) -> list[tuple[str, str]]:
    """(test id, reason) of every test skipped for want of the real recordings."""
    out = []
    for report in terminalreporter.stats.get("skipped", []):
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        if any(word in reason for word in DATA_SKIP):
            out.append((report.nodeid, reason.removeprefix("Skipped: ")))
    return out


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """Say loudly which data tests did not run and why: a run without ../shared/data passes
    with those tests skipped, and a green run must not hide that."""
    skipped = data_skips(terminalreporter)
    if not skipped:
        return
    terminalreporter.write_sep("=", f"{len(skipped)} real-data tests SKIPPED", yellow=True,
                               bold=True)
    terminalreporter.write_line(f"the real recordings were not found at {DATA} "
                                "(a folder beside the repository: shared/data/borealtc, "
                                "shared/data/tum_bmw_i3); these tests did not run:")
    for nodeid, reason in sorted(skipped):
        terminalreporter.write_line(f"  {nodeid}: {reason}")
