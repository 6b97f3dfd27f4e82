"""Issue #13 item 7: after ``pip install .`` the benches find the shipped examples (or ask for
the folder clearly), and long commands show progress on a terminal (never with --json)."""

from __future__ import annotations

import io
import shutil

import pytest
from conftest import REPO, run_cli
from logbuilders import write_ulog
from rich.console import Console

import orange_plan.cli as cli
from orange_plan import examples
from orange_plan.commands import bench_identify


def test_pyproject_ships_the_examples_as_data_files():
    import tomllib

    data_files = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"][
        "data-files"]
    assert data_files["share/orange-plan/scenarios"] == ["scenarios/*.toml"]
    assert "maps/*.geojson" in data_files["share/orange-plan/maps"]


def test_installed_examples_are_found_under_the_prefix(tmp_path, monkeypatch):
    share = tmp_path / "share" / "orange-plan"
    shutil.copytree(REPO / "scenarios", share / "scenarios")
    shutil.copytree(REPO / "maps", share / "maps")
    monkeypatch.setattr(examples, "candidate_dirs",
                        lambda kind: [tmp_path / "site-packages" / kind, share / kind])
    assert examples.examples_dir("scenarios", "--scenarios") == share / "scenarios"
    code, _, err = run_cli("bench", "online", "--only", "rusti_v1_box", "--seeds", "0")
    assert code == 2 and "--seeds = 0" in err  # got past the folder look-up


@pytest.mark.parametrize("args, needle", [
    (["bench", "reach"], "give a SCENARIO argument"),
    (["bench", "online"], "give --scenarios DIR"),
])
def test_missing_examples_ask_for_the_folder(tmp_path, monkeypatch, args, needle):
    monkeypatch.setattr(examples, "candidate_dirs", lambda kind: [tmp_path / "nowhere" / kind])
    code, _, err = run_cli(*args)
    assert code == 2 and needle in err and "not installed here" in err


def test_calibration_without_the_data_sets_asks_for_data(tmp_path, monkeypatch):
    monkeypatch.setattr(bench_identify, "DEFAULT_DATA", tmp_path / "nowhere")
    code, _, err = run_cli("bench", "calibration")
    assert code == 2 and "give --data DIR" in err


def test_convert_shows_progress_on_a_terminal_only(tmp_path, monkeypatch):
    log = write_ulog(tmp_path / "drive.ulg")
    screen = io.StringIO()
    monkeypatch.setattr(cli, "err", Console(file=screen, force_terminal=True, width=100))
    monkeypatch.setattr("orange_plan.progress.wanted", lambda as_json: not as_json)
    code, _, _ = run_cli("convert", log, "-o", tmp_path / "a.csv")
    assert code == 0 and "writing a.csv" in screen.getvalue()
    screen.truncate(0)
    code, _, _ = run_cli("convert", log, "-o", tmp_path / "b.csv", "--json")
    assert code == 0 and screen.getvalue().strip("\x00") == ""


def test_progress_bar_counts_items(monkeypatch):
    from orange_plan.progress import bar

    screen = io.StringIO()
    monkeypatch.setattr(cli, "err", Console(file=screen, force_terminal=True, width=100))
    with bar(2, "simulating", True) as tick:
        tick()
        tick()
    assert "simulating" in screen.getvalue() and "2/2" in screen.getvalue()


def test_calibration_progress_counts_every_held_out_run(tmp_path):
    from orange_plan.bench.identify import count_runs

    for name in ("ASPHALT/pro_01.csv", "ASPHALT/pro_02.csv", "SNOW/pro_03.csv", "SNOW/imu_03.csv"):
        (tmp_path / "borealtc" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "borealtc" / name).write_text("", encoding="utf-8")
    (tmp_path / "tum_bmw_i3").mkdir()
    (tmp_path / "tum_bmw_i3" / "TripA01.csv.gz").write_bytes(b"")
    assert count_runs(tmp_path, ["husky_borealtc"]) == 3
    assert count_runs(tmp_path, ["husky_borealtc", "bmw_i3_tum"]) == 4
