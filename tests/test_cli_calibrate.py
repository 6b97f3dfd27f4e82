"""``calibrate -o`` writes a scenario that every command loads: calibrate -> predict -> reach
for every shipped scenario (real recordings where the data set has that robot, else a short
simulated one)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli

from orange_plan.context import load_context
from orange_plan.sim.ranges import probe_route
from orange_plan.sim.simulator import simulate
from orange_plan.telemetry.importers import read_log
from orange_plan.telemetry.recording import write_recording

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
SCENARIOS = sorted(p.stem for p in (REPO / "scenarios").glob("*.toml"))
RUSTI_V2 = "rusti_v2_grass_2200mAh_v0952"
"""The Rusti V2.0 scenario of the default run; its 11 siblings (same robot, another surface,
pack or speed) run with ``-m slow``."""
ROUND_TRIP = [pytest.param(n, marks=pytest.mark.slow)
              if n.startswith("rusti_v2_") and n != RUSTI_V2 else n for n in SCENARIOS]
REAL = {"husky_a200": "borealtc/ASPHALT/pro_00.csv", "bmw_i3": "tum_bmw_i3/TripA01.csv.gz"}
"""Scenarios with real recordings (husky_a200 + pro_00 once failed to calibrate)."""
REAL_ROWS = 3000
"""Rows of a real log kept (the BMW trip's first 5 minutes keep the test fast)."""


def recording_for(name: str, folder: Path) -> Path:
    """The real log converted to a recording, else one lap of four short probe rays from home
    driven by the simulator (the scenario's own model, no truth effects)."""
    path = folder / "rec.csv"
    if name in REAL and (DATA / REAL[name]).exists():
        return write_recording(read_log(DATA / REAL[name])[0].iloc[:REAL_ROWS], path)
    ctx = load_context(REPO / "scenarios" / f"{name}.toml")
    route = probe_route(ctx, n_rays=4, max_ray_m=15.0).with_default_speed(ctx.cruise_speed_mps)
    return write_recording(simulate(ctx, route, seed=0).frame, path)


@pytest.mark.timeout(120)
@pytest.mark.parametrize("name", ROUND_TRIP)
def test_calibrated_scenario_loads_in_every_command(tmp_path, name):
    rec = recording_for(name, tmp_path)
    out = tmp_path / "calibrated.toml"
    code, stdout, stderr = run_cli("calibrate", rec, "--scenario", REPO / "scenarios" / f"{name}.toml",
                                   "-o", out, "--json")
    assert code == 0, stderr
    fit = json.loads(stdout)["fit"]
    assert fit["discrepancy_runs"] == 0  # one recording: the a priori discrepancy is kept

    code, stdout, stderr = run_cli("predict", rec, "--scenario", out, "--json")
    assert code == 0, stderr
    report = json.loads(stdout)
    # the calibrated model replays its own recording closely, with an honest spread
    assert abs(report["energy_error_pct"]) < 15.0
    assert 0.0 < report["energy_predicted_sd_J"] < np.inf

    code, stdout, stderr = run_cli("reach", out, "--vertices", "60", "--json")
    assert code == 0, stderr
    report = json.loads(stdout)
    assert report["home_reachable"] and np.isfinite(report["reserve_J"])
