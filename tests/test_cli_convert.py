"""``orange-plan convert``: output contract, guessing and the bad-input contract (exit 2)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli
from logbuilders import write_rosbag2, write_ulog

from orange_plan.telemetry.recording import load_recording

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def test_convert_ulog_to_csv_json(tmp_path):
    log = write_ulog(tmp_path / "drive.ulg")
    out = tmp_path / "rec.csv"
    code, stdout, _ = run_cli("convert", log, "-o", out, "--json")
    assert code == 0
    report = json.loads(stdout)
    assert report["format"] == "ulog" and report["rows"] == 21
    assert report["energy_J"] == pytest.approx(480.0)
    rec = load_recording(out)
    assert {"t_s", "power_W", "x_m", "y_m", "z_m", "v_mps", "yaw_rate_radps",
            "accel_mps2"} <= set(rec.frame.columns)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["drive.ulg", "rec.csv"]


def test_convert_mcap_to_parquet_with_explicit_format(tmp_path):
    bag = write_rosbag2(tmp_path / "bag", "mcap")
    out = tmp_path / "rec.parquet"
    code, stdout, _ = run_cli("convert", bag, "--format", "rosbag2", "-o", out)
    assert code == 0 and "rosbag2" in stdout
    assert np.allclose(load_recording(out).frame["power_W"], 48.0)


@pytest.mark.parametrize("args, needle", [
    (["--format", "csvlog"], "unknown format 'csvlog'; allowed: ulog, rosbag1, rosbag2"),
    ([], "cannot tell the log format; give --format, one of ulog"),
])
def test_convert_unknown_format_exits_2(tmp_path, args, needle):
    log = tmp_path / "log.txt"
    log.write_text("nothing to see")
    code, stdout, stderr = run_cli("convert", log, *args, "-o", tmp_path / "r.csv", "--json")
    assert code == 2 and stdout == ""
    assert needle in stderr and len(stderr.strip().splitlines()) == 1


def test_convert_bad_output_extension_exits_2(tmp_path):
    log = write_ulog(tmp_path / "drive.ulg")
    code, _, stderr = run_cli("convert", log, "-o", tmp_path / "rec.xlsx")
    assert code == 2 and "unknown recording extension" in stderr


def test_convert_missing_log_exits_2(tmp_path):
    code, _, stderr = run_cli("convert", tmp_path / "none.ulg", "-o", tmp_path / "r.csv")
    assert code == 2 and "no such file" in stderr


def test_convert_real_borealtc_run(tmp_path):
    log = DATA / "borealtc" / "SNOW" / "pro_00.csv"
    if not log.exists():
        pytest.skip("real data not found at ../shared/data/borealtc")
    code, stdout, _ = run_cli("convert", log, "-o", tmp_path / "r.csv", "--json")
    assert code == 0
    report = json.loads(stdout)
    assert report["format"] == "borealtc" and report["rows"] > 100
