"""Replay (``predict``): the model's power along a recording's motion, against hand values."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import run_cli, write_scenario

from orange_plan.context import load_context
from orange_plan.telemetry.importers import read_log
from orange_plan.telemetry.recording import recording_from_frame, write_recording
from orange_plan.telemetry.replay import replay, replay_context

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"

# The conftest yard scenario on default ground (x < 10): P_anc = (2 + 0.1*10 + 3 + 1)/(1 - 0.2)
# = 8.75 W; rolling 0.05 * 10 kg * 9.81 / (0.8 * 0.9) = 6.8125 N, at 0.5 m/s 3.40625 W.
HAND_POWER_W = 8.75 + 6.8125 * 0.5


def drive(power_W: float, n: int = 81, dt: float = 0.2) -> pd.DataFrame:
    t = np.arange(n) * dt
    return pd.DataFrame({"t_s": t, "power_W": power_W, "x_m": 1.0 + 0.5 * t, "y_m": 5.0})


def test_replay_matches_the_hand_computed_power(tmp_path):
    ctx = load_context(write_scenario(tmp_path))
    result = replay_context(recording_from_frame(drive(HAND_POWER_W)), ctx)
    assert np.allclose(result.predicted_W, HAND_POWER_W)
    assert result.energy_error_pct == pytest.approx(0.0, abs=1e-9)
    assert result.rmse_W == pytest.approx(0.0, abs=1e-9)
    assert result.duration_s == pytest.approx(16.0)


def test_predicted_sd_is_parameter_plus_discrepancy_by_hand(tmp_path):
    # 16 s at constant motion: energies by term, ancillary (2 + 3 + 1)/0.8 x 16 = 120 J,
    # sensor 0.1/0.8 x 10 Hz x 16 = 20 J, rolling 3.40625 W x 16 = 54.5 J (grade 0). A priori
    # stderr 10 % of each coefficient: var = 0.01 (120^2 + 20^2 + 54.5^2); discrepancy 0.2 E.
    ctx = load_context(write_scenario(tmp_path, set={"model": {"discrepancy_rel_sd": 0.2}}))
    result = replay_context(recording_from_frame(drive(HAND_POWER_W)), ctx)
    energy = HAND_POWER_W * 16.0
    assert result.energy_predicted_J == pytest.approx(energy)
    var = 0.01 * (120.0**2 + 20.0**2 + 54.5**2) + (0.2 * energy) ** 2
    assert result.energy_predicted_sd_J == pytest.approx(np.sqrt(var))


def test_replay_error_sign_and_rmse(tmp_path):
    ctx = load_context(write_scenario(tmp_path))
    result = replay(recording_from_frame(drive(2 * HAND_POWER_W)), ctx.model, ctx.world,
                    ctx.conditions.sensor_rate_Hz)
    assert result.energy_error_pct == pytest.approx(-50.0)   # predicts half: under-predicts
    assert result.rmse_W == pytest.approx(HAND_POWER_W)
    assert result.energy_recorded_J == pytest.approx(2 * HAND_POWER_W * 16.0)


def test_predict_cli_json_and_png(tmp_path):
    scenario = write_scenario(tmp_path)
    rec = write_recording(drive(HAND_POWER_W), tmp_path / "rec.csv")
    png = tmp_path / "replay.png"
    code, stdout, _ = run_cli("predict", rec, "--scenario", scenario, "--png", png, "--json")
    assert code == 0
    report = json.loads(stdout)
    for key in ("energy_recorded_J", "energy_predicted_J", "energy_predicted_sd_J",
                "energy_error_pct", "rmse_W", "duration_s"):
        assert isinstance(report[key], float)
    assert report["energy_error_pct"] == pytest.approx(0.0, abs=1e-9)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("content, needle", [
    ("t_s,power_W\n0,1\n1,1\n", "'v_mps'"),
    ("t_s,power_W,v_mps\n0,1,1\n1,x,1\n", "'power_W' holds text 'x' at row 1"),
    ("", "empty"),
    ("t_s,power_W,v_mps\n0,1,1\n", "one row"),
    ("t_s,power_W,v_mps\n1700000000000000000,1,1\n1700000000100000000,1,1\n", "epoch"),
])
def test_predict_malformed_recording_exits_2_with_one_line(tmp_path, content, needle):
    scenario = write_scenario(tmp_path)
    rec = tmp_path / "bad.csv"
    rec.write_text(content)
    code, stdout, stderr = run_cli("predict", rec, "--scenario", scenario, "--json")
    assert code == 2
    assert stdout == ""
    assert needle in stderr and len(stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("scenario, log", [
    ("husky_a200", "borealtc/ASPHALT/pro_01.csv"),
    ("bmw_i3", "tum_bmw_i3/TripA01.csv.gz"),
])
def test_real_data_replays_through_the_shipped_scenarios(scenario, log):
    path = DATA / log
    if not path.exists():
        pytest.skip(f"real data not found at ../shared/data/{log}")
    ctx = load_context(REPO / "scenarios" / f"{scenario}.toml")
    result = replay_context(recording_from_frame(read_log(path)[0], str(path)), ctx)
    assert np.all(np.isfinite(result.predicted_W))
    # Uncalibrated a-priori model: same order of magnitude as the measurement.
    assert -90.0 < result.energy_error_pct < 100.0
