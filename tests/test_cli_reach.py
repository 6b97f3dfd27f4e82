"""``orange-plan reach``: JSON contract, goals CSV, PNG, bad input (one line, exit 2)."""

from __future__ import annotations

import json

import pytest
from conftest import run_cli
from planning_worlds import write_world

pytestmark = pytest.mark.timeout(60)

KEYS = {"home_xy_m", "from_xy_m", "energy_available_J", "energy_used_J", "reserve_J",
        "home_reachable", "goals"}
GOAL_KEYS = {"x_m", "y_m", "valid", "feasible", "energy_to_goal_J", "energy_goal_to_home_J",
             "margin_J"}


@pytest.fixture
def scenario(tmp_path):
    return write_world(tmp_path, obstacles=[(10, 5, 14, 25)], hill=(28, 20, 4.0, 5.0))


@pytest.fixture
def goals_csv(tmp_path):
    f = tmp_path / "goals.csv"
    f.write_text("x_m,y_m,name\n35,25,far\n12,10,in_box\n60,5,outside\n", encoding="utf-8")
    return f


def test_json_contract(scenario, goals_csv):
    code, out, err = run_cli("reach", scenario, "--goals", goals_csv, "--vertices", "200",
                             "--json")
    assert code == 0, err
    report = json.loads(out)
    assert set(report) >= KEYS
    assert report["home_reachable"] is True and report["from_xy_m"] == report["home_xy_m"]
    far, in_box, outside = report["goals"]
    assert set(far) >= GOAL_KEYS and far["name"] == "far" and far["valid"] and far["feasible"]
    assert far["margin_J"] == pytest.approx(report["energy_available_J"] - far["energy_to_goal_J"]
                                            - far["energy_goal_to_home_J"] - far["reserve_J"])
    assert not in_box["valid"] and not in_box["feasible"] and "obstacle" in in_box["reason"]
    assert not outside["valid"] and "boundary" in outside["reason"]


def test_from_and_energy_used(scenario, goals_csv):
    code, out, _ = run_cli("reach", scenario, "--from", "30,5", "--energy-used-J", "3300",
                           "--goals", goals_csv, "--vertices", "200", "--json")
    report = json.loads(out)
    assert code == 0 and report["from_xy_m"] == [30.0, 5.0] and report["energy_used_J"] == 3300
    assert report["home_reachable"] is False or report["goals"][0]["feasible"] is False


def test_png_and_human_output(scenario, goals_csv, tmp_path):
    png = tmp_path / "out" / "reach.png"
    code, out, err = run_cli("reach", scenario, "--goals", goals_csv, "--png", png,
                             "--vertices", "200")
    assert code == 0, err
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "far" in out and "wrote" in out
    assert not list(png.parent.glob(".reach.png*"))  # no temporary file left


@pytest.mark.parametrize("args, text", [
    (["--from", "12,10"], "--from (12, 10) m is outside the boundary or inside an obstacle"),
    (["--from", "abc"], "--from must be X,Y"),
    (["--energy-used-J", "-5"], "--energy-used-J = -5 must be in"),
    (["--time-used-s", "-5"], "--time-used-s must be a number >= 0"),
    (["--goals", "missing.csv"], "goals file not found"),
    (["--png", "x.jpg"], "must end in .png"),
])
def test_bad_input_one_line_exit_2(scenario, args, text):
    code, out, err = run_cli("reach", scenario, "--vertices", "50", *args)
    assert code == 2 and out == ""
    assert text in err and len(err.strip().splitlines()) == 1


def test_json_gives_each_feasible_goal_a_drivable_route(scenario, goals_csv):
    code, out, err = run_cli("reach", scenario, "--goals", goals_csv, "--vertices", "200",
                             "--json")
    assert code == 0, err
    far, in_box, _ = json.loads(out)["goals"]
    assert far["feasible"]
    path = far["path_xy_m"]
    assert len(path) >= 2 and path[0] == path[-1] == json.loads(out)["home_xy_m"]
    assert [35.0, 25.0] in path
    assert far["speed_mps"] == [json.loads(out)["speed_mps"]] * len(path)
    assert "path_xy_m" not in in_box and "speed_mps" not in in_box


def test_time_limit_reason_in_json_and_text(tmp_path, goals_csv):
    scenario = write_world(tmp_path, obstacles=[(10, 5, 14, 25)], time_limit_s=30.0)
    code, out, err = run_cli("reach", scenario, "--goals", goals_csv, "--vertices", "200",
                             "--json")
    assert code == 0, err
    report = json.loads(out)
    assert report["time_limit_s"] == 30.0
    far = report["goals"][0]
    assert not far["feasible"] and far["duration_s"] > 30.0
    assert "exceeds mission.time_limit_s = 30 s" in far["reason"]
    code, out, _ = run_cli("reach", scenario, "--goals", goals_csv, "--vertices", "200")
    assert code == 0 and "mission.time_limit_s" in out


def test_a_goal_unlikely_to_get_home_is_said_so(tmp_path):
    """A goal feasible under its reserve rule whose round trip leaves too little for the
    model's uncertainty: one warning line on stderr, the same text in ``warnings``."""
    from orange_plan.planning.reach import RETURN_PROBABILITY_WARN

    scenario = write_world(tmp_path, reserve={"fraction": 0.0})
    goals = tmp_path / "goals.csv"
    goals.write_text("x_m,y_m,name\n35,25,far\n4,4,near\n", encoding="utf-8")
    first = json.loads(run_cli("reach", scenario, "--goals", goals, "--vertices", "200",
                               "--json")[1])
    assert first["warnings"] == [] and first["home_return_probability"] == 1.0
    far = first["goals"][0]
    # used energy that leaves the far goal's round trip a margin of 1 J: feasible, and about
    # as likely to fall short as not
    used = first["energy_available_J"] - far["energy_to_goal_J"] - far["energy_goal_to_home_J"] - 1
    code, out, err = run_cli("reach", scenario, "--goals", goals, "--vertices", "200",
                             "--energy-used-J", str(used), "--json")
    assert code == 0, err
    report = json.loads(out)
    far, near = report["goals"]
    assert far["feasible"] and far["return_probability"] < RETURN_PROBABILITY_WARN
    assert near["return_probability"] >= RETURN_PROBABILITY_WARN
    lines = [line for line in err.splitlines() if "warning" in line]
    assert len(lines) == 1 == len(report["warnings"]) and report["warnings"][0] in lines[0]
    assert "1 of the 2 feasible goals (lowest: goal far)" in lines[0]
