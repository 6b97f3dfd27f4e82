"""``orange-plan simulate``, ``calibrate`` and ``bench calibration|online``: output contracts, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from conftest import run_cli, write_scenario

from orange_plan.context import load_context

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
ROUTE = "x_m,y_m\n1,1\n18,1\n18,4\n1,4\n1,1\n"


@pytest.fixture
def files(tmp_path):
    scenario = write_scenario(tmp_path)
    (tmp_path / "route.csv").write_text(ROUTE, encoding="utf-8")
    (tmp_path / "truth.toml").write_text("[coefficients]\nrolling_kg = 20.0\n[noise]\n"
                                         "power_std_W = 0.3\n", encoding="utf-8")
    return tmp_path, scenario


def test_simulate_writes_a_recording_and_one_json_object(files):
    folder, scenario = files
    code, stdout, _ = run_cli("simulate", scenario, folder / "route.csv", "-o", folder / "rec.csv",
                              "--truth", folder / "truth.toml", "--seed", "3", "--to-depletion",
                              "--max-duration-s", "600", "--json")
    assert code == 0
    report = json.loads(stdout)
    assert report["samples"] == len(pd.read_csv(folder / "rec.csv"))
    assert report["duration_s"] == pytest.approx(600.0, abs=0.2)
    columns = set(pd.read_csv(folder / "rec.csv").columns)
    assert {"t_s", "x_m", "y_m", "z_m", "v_mps", "yaw_rate_radps", "accel_mps2", "power_W",
            "soc", "payload_kg", "sensor_rate_Hz", "surface"} <= columns


@pytest.mark.parametrize("rate_hz", ["10", "3"])
def test_simulate_and_predict_give_one_recording_one_duration(files, rate_hz):
    folder, scenario = files
    code, stdout, _ = run_cli("simulate", scenario, folder / "route.csv", "-o", folder / "r.csv",
                              "--rate-hz", rate_hz, "--json")
    assert code == 0
    simulated = json.loads(stdout)["duration_s"]
    code, stdout, _ = run_cli("predict", folder / "r.csv", "--scenario", scenario, "--json")
    assert code == 0
    predicted = json.loads(stdout)["duration_s"]
    t = pd.read_csv(folder / "r.csv")["t_s"]
    assert simulated == pytest.approx(predicted) == pytest.approx(t.iloc[-1] - t.iloc[0])


def test_calibrate_json_and_written_scenario(files):
    folder, scenario = files
    run_cli("simulate", scenario, folder / "route.csv", "-o", folder / "rec.csv", "--truth",
            folder / "truth.toml", "--to-depletion", "--max-duration-s", "900")
    code, stdout, _ = run_cli("calibrate", folder / "rec.csv", "--scenario", scenario,
                              "-o", folder / "fitted.toml", "--json")
    assert code == 0
    report = json.loads(stdout)
    assert set(report) >= {"params", "stderr", "fit"}
    assert set(report["fit"]) >= {"rmse_W", "holdout_rmse_W", "energy_error_pct"}
    assert report["params"]["rolling_kg"] == pytest.approx(20.0, abs=3 * report["stderr"]["rolling_kg"])
    fitted = load_context(folder / "fitted.toml")
    assert fitted.model.coefficient("rolling_kg") == pytest.approx(report["params"]["rolling_kg"])
    code, stdout, _ = run_cli("calibrate", folder / "rec.csv", "--scenario", scenario)
    assert code == 0 and "rolling_kg" in stdout


@pytest.mark.parametrize(("args", "message"), [
    (["simulate", "{s}", "{d}/missing.csv", "-o", "{d}/r.csv"], "route file not found"),
    (["simulate", "{s}", "{d}/route.csv", "-o", "{d}/r.txt"], "unknown recording extension"),
    (["simulate", "{s}", "{d}/route.csv", "-o", "{d}/r.csv", "--truth", "{d}/bad.toml"],
     "unknown table [wnd]"),
    (["calibrate", "{d}/empty.csv", "--scenario", "{s}"], "empty"),
    (["calibrate", "{d}/route.csv", "--scenario", "{s}"], "missing required column 't_s'"),
    (["calibrate", "{d}/rec.csv", "--scenario", "{s}", "--terms", "ancillary,hvca"],
     "unknown term 'hvca'"),
])
def test_bad_input_is_one_line_and_exit_2(files, args, message):
    folder, scenario = files
    (folder / "bad.toml").write_text("[wnd]\nmean_mps = 1\n", encoding="utf-8")
    (folder / "empty.csv").write_text("", encoding="utf-8")
    pd.DataFrame({"t_s": [0.0, 0.1, 0.2], "power_W": [5.0, 5.0, 5.0],
                  "v_mps": [0.0, 0.0, 0.0]}).to_csv(folder / "rec.csv", index=False)
    code, stdout, stderr = run_cli(*[a.format(s=scenario, d=folder) for a in args])
    assert code == 2
    assert stdout == ""
    assert message in stderr and len(stderr.strip().splitlines()) == 1


@pytest.mark.skipif(not (DATA / "tum_bmw_i3").is_dir(), reason="real data not present in ../shared/data")
def test_calibrate_a_real_bmw_trip(tmp_path):
    from orange_plan.telemetry.importers.tum_bmw_i3 import read_tum_bmw_i3
    from orange_plan.telemetry.recording import write_recording

    repo = Path(__file__).resolve().parents[1]
    write_recording(read_tum_bmw_i3(DATA / "tum_bmw_i3" / "TripA04.csv.gz"), tmp_path / "a04.csv")
    code, stdout, _ = run_cli("calibrate", tmp_path / "a04.csv", "--scenario",
                              repo / "scenarios" / "bmw_i3.toml", "--json")
    assert code == 0
    report = json.loads(stdout)
    assert "regen_efficiency" in report["params"]
    assert report["fit"]["energy_error_pct"] < 10.0


@pytest.mark.parametrize(("args", "message"), [
    (["bench", "online", "--seeds", "0"], "--seeds = 0 must be >= 1"),
    (["bench", "calibration", "--only", "husky"], "unknown dataset 'husky'"),
    (["bench", "calibration", "--data", "no/such/folder"], "folder not found"),
])
def test_bench_identify_bad_input(args, message):
    code, stdout, stderr = run_cli(*args)
    assert code == 2 and stdout == "" and message in stderr


@pytest.mark.skipif(not (DATA / "borealtc").is_dir(), reason="real data not present in ../shared/data")
def test_bench_calibration_reports_offline_and_online_on_real_runs(tmp_path):
    """Four short BorealTC runs (two per fold): the JSON contract of `bench calibration`."""
    for folder, n in (("ASPHALT", "02"), ("FLOORING", "01"), ("FLOORING", "02"), ("FLOORING", "08")):
        (tmp_path / "borealtc" / folder).mkdir(parents=True, exist_ok=True)
        for kind in ("pro", "imu"):
            src = DATA / "borealtc" / folder / f"{kind}_{n}.csv"
            (tmp_path / "borealtc" / folder / src.name).symlink_to(src)
    code, stdout, _ = run_cli("bench", "calibration", "--data", tmp_path, "--only",
                              "husky_borealtc", "--json")
    assert code == 0
    report = json.loads(stdout)
    from test_json_docs import compare

    compare("bench calibration", report)  # docs/json.md lists exactly these keys
    (summary,) = report["summary"]
    assert summary["held_out_runs"] == 4 and len(report["runs"]) == 4
    for key in ("mean_abs_error_pct", "online_mean_abs_error_pct",
                "online_mean_abs_error_over_run_pct", "online_prior_mean_abs_error_pct"):
        assert 0.0 <= summary[key] < 100.0, key
    row = report["runs"][0]
    assert row["energy_recorded_J"] > 0 and row["online_error_mean_abs_pct"] >= 0
