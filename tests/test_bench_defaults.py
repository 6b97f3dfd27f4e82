"""After ``pip install .`` the benches find the shipped examples (or ask for
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


def test_pyproject_ships_the_examples_as_data_files():
    import tomllib

    data_files = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"][
        "data-files"]
    assert data_files["share/orange-plan/scenarios"] == ["scenarios/*.toml"]
    assert "maps/*.geojson" in data_files["share/orange-plan/maps"]


@pytest.fixture
def installed(tmp_path, monkeypatch):
    """A faked ``pip install .`` layout: the examples under ``<prefix>/share/orange-plan/``,
    the package in site-packages (no checkout beside it), the working folder elsewhere."""
    prefix = tmp_path / "prefix"
    share = prefix / "share" / "orange-plan"
    shutil.copytree(REPO / "scenarios", share / "scenarios")
    shutil.copytree(REPO / "maps", share / "maps")
    monkeypatch.setattr(examples.sys, "prefix", str(prefix))
    monkeypatch.setattr(examples.site, "getuserbase", lambda: str(tmp_path / "userbase"))
    monkeypatch.setattr(examples, "CHECKOUT", prefix / "lib" / "site-packages")
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    return share


def test_installed_examples_are_found_under_the_prefix(installed):
    assert examples.examples_dir("scenarios", "--scenarios") == installed / "scenarios"
    code, _, err = run_cli("bench", "online", "--only", "rusti_v1_box", "--seeds", "0")
    assert code == 2 and "--seeds = 0" in err  # got past the folder look-up


def test_the_working_folder_comes_before_the_installed_examples(installed, tmp_path):
    (tmp_path / "elsewhere" / "scenarios").mkdir()
    assert examples.find_dir("scenarios") == tmp_path / "elsewhere" / "scenarios"


def test_serve_uses_the_installed_examples(installed):
    from orange_plan.service.scenarios import ScenarioLibrary

    assert "kiwibot_campus" in ScenarioLibrary().names()
    assert ScenarioLibrary().maps_dir == installed / "maps"


def test_bench_plan_finds_an_installed_scenario_by_name(installed):
    from orange_plan.bench.plan import repo_scenario

    assert repo_scenario("rusti_v1_box") == \
        installed / "scenarios" / "rusti_v1_box.toml"


@pytest.mark.parametrize("args, needle", [
    (["bench", "reach"], "give a SCENARIO argument"),
    (["bench", "online"], "give --scenarios DIR"),
    (["bench", "calibration"], "give --data DIR"),
    (["bench", "plan", "--scenarios", "rusti_v1_box"], "give a .toml path in --scenarios"),
])
def test_missing_folders_say_where_they_looked(installed, tmp_path, monkeypatch, args, needle):
    shutil.rmtree(installed)
    code, _, err = run_cli(*args)
    flat = " ".join(err.split())
    assert code == 2 and needle in flat and "not found (looked in" in flat
    assert str(tmp_path / "elsewhere") in flat and str(installed) in flat


def test_the_data_sets_are_found_in_the_working_folder(installed, tmp_path):
    from orange_plan.commands.bench_identify import _default_data

    (tmp_path / "elsewhere" / "data").mkdir()
    assert _default_data() == tmp_path / "elsewhere" / "data"
    (installed / "data").mkdir()
    (tmp_path / "elsewhere" / "data").rmdir()
    assert _default_data() == installed / "data"


def test_report_paper_finds_the_data_sets_and_says_where_it_looked(installed, tmp_path,
                                                                    monkeypatch):
    from orange_plan.report import paper

    seen = []

    def fake_generate(out_dir, scenario_dir, data_dir, trials, seed, tick=None):
        seen.append((scenario_dir, data_dir))
        return {"files": []}

    monkeypatch.setattr(paper, "generate", fake_generate)
    (installed / "data").mkdir()
    code, _, _ = run_cli("report", "paper", "-o", tmp_path / "r", "--json")
    assert code == 0 and seen[-1] == (installed / "scenarios", installed / "data")
    (installed / "data").rmdir()
    code, _, _ = run_cli("report", "paper", "-o", tmp_path / "r", "--json")
    assert code == 0 and seen[-1][1] is None
    note = paper.missing_data_note()
    assert str(installed / "data") in note and str(tmp_path / "elsewhere" / "data") in note


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


def test_progress_bar_counts_items():
    from orange_plan.progress import bar

    screen = io.StringIO()
    with bar(2, "simulating", Console(file=screen, force_terminal=True, width=100)) as tick:
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
