"""Hostile input on the command line: every bad number or path is one line, exit code 2.

A number no command can use (NaN, infinities, negative sizes, seeds beyond the generators'
range, integers beyond 64 bits) and a path that cannot serve (empty, a folder, a missing file,
a folder that cannot be written) are refused naming the option, before any long work starts;
never a traceback, never "internal error", never exit 1.
"""

from __future__ import annotations

import socket
from pathlib import Path

import pandas as pd
import pytest
from conftest import REPO, run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

BOX = REPO / "scenarios" / "rusti_v1_box.toml"
DRONE = REPO / "scenarios" / "ar_drone_wind.toml"
UNWRITABLE = Path("/proc/nope")
"""A folder no one can create a file in, superuser included (Linux's /proc)."""
needs_proc = pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")


def one_line(err: str) -> str:
    """The single error line (fails on a second line, a traceback or an internal error)."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("orange-plan: error: "), err
    assert "Traceback" not in err and "internal error" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """Valid inputs for every command: a route and a recording on the lab box, a plan on the
    drone field (an aerial robot, so --altitude-m applies)."""
    from orange_plan.context import load_context
    from orange_plan.sim.route import load_route
    from orange_plan.sim.simulator import simulate
    from orange_plan.telemetry.recording import write_recording

    folder = tmp_path_factory.mktemp("hostile")
    route = folder / "route.csv"
    route.write_text("x_m,y_m\n1,1\n7,1\n7,1.5\n1,1.5\n1,1\n", encoding="utf-8")
    recording = folder / "rec.csv"
    result = simulate(load_context(BOX), load_route(route), seed=0, sample_rate_Hz=5.0)
    write_recording(result.frame, recording)
    plan = folder / "plan.geojson"
    plan.write_text('{"type": "FeatureCollection", "features": [{"type": "Feature", '
                    '"properties": {"kind": "tour", "speed_mps": [3, 3, 3]}, "geometry": '
                    '{"type": "LineString", "coordinates": [[30, 30], [40, 30], [30, 30]]}}]}',
                    encoding="utf-8")
    return {"folder": folder, "route": route, "recording": recording, "plan": plan}


def command_line(files, command: str) -> list[str]:
    """A valid, fast invocation of ``command`` (options are appended after it)."""
    f, out = files, files["folder"]
    return {
        "range": ["range", BOX],
        "plan": ["plan", BOX, "-o", out / "p.geojson", "--vertices", "50"],
        "reach": ["reach", BOX, "--vertices", "50"],
        "simulate": ["simulate", BOX, f["route"], "-o", out / "sim.csv"],
        "predict": ["predict", f["recording"], "--scenario", BOX],
        "calibrate": ["calibrate", f["recording"], "--scenario", BOX],
        "diagnose": ["diagnose", f["recording"], "--scenario", BOX],
        "export": ["export", f["plan"], "--scenario", DRONE, "-o", out / "m.plan",
                   "--altitude-m", "20"],
    }[command]


NUMBER_OPTIONS = [
    ("plan", "--energy-used-J"), ("plan", "--time-s"), ("plan", "--seed"),
    ("reach", "--energy-used-J"), ("reach", "--time-used-s"), ("reach", "--seed"),
    ("simulate", "--seed"), ("simulate", "--rate-hz"), ("simulate", "--max-duration-s"),
    ("calibrate", "--grade-window-m"), ("diagnose", "--grade-window-m"),
    ("export", "--altitude-m"),
]
"""Every number option of the commands above except --vertices (its own tests)."""
BAD_NUMBERS = st.sampled_from(["nan", "NaN", "inf", "-inf", "1e400", "-1", "-0.5", "-1e9",
                               str(2**64), str(-(2**70)), "99999999999999999999", ""])
"""Values no number option accepts ("" and non-numbers: the parser's own one line)."""


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=st.sampled_from(NUMBER_OPTIONS), value=BAD_NUMBERS)
def test_bad_numbers_are_one_line_exit_2(files, case, value):
    command, option = case
    code, _, err = run_cli(*command_line(files, command), option, value)
    assert code == 2, err
    line = one_line(err)
    assert option in line or "Invalid value" in line


INPUT_ARGS = [("range", 1), ("plan", 1), ("reach", 1), ("simulate", 1), ("simulate", 2),
              ("predict", 1), ("predict", 3), ("calibrate", 1), ("calibrate", 3),
              ("diagnose", 1), ("diagnose", 3), ("export", 1), ("export", 3)]
"""(command, index in its command line of an input file): scenarios, routes, recordings,
plans."""


OUTPUT_OPTIONS = [("plan", "-o", ".geojson"), ("plan", "--png", ".png"),
                  ("reach", "--png", ".png"), ("simulate", "-o", ".csv"),
                  ("predict", "--png", ".png"), ("calibrate", "-o", ".toml"),
                  ("diagnose", "-o", ".toml"), ("diagnose", "--png", ".png"),
                  ("export", "-o", ".plan")]
"""Every file-writing option of the commands above, with a name ending it accepts."""


def bad_path(files, kind: str, suffix: str) -> str:
    folder = files["folder"]
    return {"empty": "", "folder": str(folder), "missing": str(folder / f"missing{suffix}"),
            "unwritable": str(UNWRITABLE / f"x{suffix}")}[kind]


@needs_proc
@settings(max_examples=30, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=st.sampled_from(INPUT_ARGS), kind=st.sampled_from(["empty", "folder", "missing",
                                                                "unwritable"]))
def test_bad_input_paths_are_one_line_exit_2(files, case, kind):
    command, index = case
    args = command_line(files, command)
    args[index] = bad_path(files, kind, Path(str(args[index])).suffix)
    code, _, err = run_cli(*args)
    assert code == 2, err
    one_line(err)


@needs_proc
@settings(max_examples=30, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=st.sampled_from(OUTPUT_OPTIONS), kind=st.sampled_from(["empty", "folder",
                                                                    "unwritable"]))
def test_bad_output_paths_are_one_line_exit_2(files, case, kind):
    command, option, suffix = case
    args = command_line(files, command)
    if option in args:  # replace the valid one
        i = args.index(option)
        del args[i:i + 2]
    code, _, err = run_cli(*args, option, bad_path(files, kind, suffix))
    assert code == 2, err
    one_line(err)


# --- the walkthrough's cases, one by one -----------------------------------------------------


@pytest.mark.parametrize("args, option", [
    (["plan", BOX, "-o", "{out}/p.geojson", "--time-s", "inf"], "--time-s"),
    (["plan", BOX, "-o", "{out}/p.geojson", "--seed", "99999999999999999999"], "--seed"),
    (["reach", BOX, "--seed", "-1"], "--seed"),
    (["simulate", BOX, "{route}", "-o", "{out}/s.csv", "--seed", str(2**32)], "--seed"),
    (["diagnose", "{recording}", "--scenario", BOX, "--grade-window-m", "nan"],
     "--grade-window-m"),
    (["calibrate", "{recording}", "--scenario", BOX, "--grade-window-m", "-5"],
     "--grade-window-m"),
    (["export", "{plan}", "--scenario", DRONE, "-o", "{out}/m.plan", "--altitude-m", "1e9"],
     "--altitude-m"),
    (["export", "{plan}", "--scenario", DRONE, "-o", "{out}/m.plan", "--altitude-m", "-20"],
     "--altitude-m"),
])
def test_walkthrough_numbers_name_their_option(files, args, option):
    subs = {"out": files["folder"], **{k: v for k, v in files.items() if k != "folder"}}
    args = [str(a).format(**subs) for a in args]
    code, _, err = run_cli(*args)
    assert code == 2 and option in one_line(err)


def test_export_without_altitude_says_what_is_missing(files):
    code, _, err = run_cli("export", files["plan"], "--scenario", DRONE, "-o",
                           files["folder"] / "m.plan")
    line = one_line(err)
    assert code == 2 and "--altitude-m" in line and "None" not in line


@needs_proc
def test_unwritable_plan_output_is_refused_before_planning(monkeypatch):
    import orange_plan.planning.tour as tour

    def must_not_run(*args, **kwargs):
        raise AssertionError("planned before checking the output")

    monkeypatch.setattr(tour, "plan_tour", must_not_run)
    code, _, err = run_cli("plan", BOX, "-o", UNWRITABLE / "out.geojson", "--vertices", "50")
    assert code == 2 and "-o" in one_line(err)


@needs_proc
def test_serve_refuses_an_unwritable_db():
    code, _, err = run_cli("serve", "--db", UNWRITABLE / "y.sqlite", "--port", "0")
    assert code == 2 and "--db" in one_line(err)


def test_serve_refuses_a_busy_port_in_one_line(tmp_path):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code, _, err = run_cli("serve", "--port", port, "--db", tmp_path / "s.sqlite")
    assert code == 2 and str(port) in one_line(err) and "in use" in err
    assert not (tmp_path / "s.sqlite").exists()


def test_calibrate_refuses_a_recording_far_off_the_map(files, tmp_path):
    frame = pd.read_csv(files["recording"])
    frame["x_m"] = frame["x_m"] + 100_000.0
    far = tmp_path / "far.csv"
    frame.to_csv(far, index=False)
    code, _, err = run_cli("calibrate", far, "--scenario", BOX)
    assert code == 2 and "outside the map" in one_line(err)


@needs_proc
@pytest.mark.parametrize("args, option, work", [
    (["bench", "plan", "--quick", "--png", UNWRITABLE / "b.png"], "--png",
     "orange_plan.bench.plan:run_plan_bench"),
    (["bench", "plan", "--quick", "--out", UNWRITABLE / "b.json"], "--out",
     "orange_plan.bench.plan:run_plan_bench"),
    (["bench", "mission", "--quick", "--png", UNWRITABLE / "m.png"], "--png",
     "orange_plan.bench.mission:run_mission_study"),
    (["bench", "mission", "--quick", "--out", UNWRITABLE / "m.json"], "--out",
     "orange_plan.bench.mission:run_mission_study"),
    (["report", "paper", "-o", UNWRITABLE / "report"], "-o", "orange_plan.report.paper:generate"),
])
def test_long_commands_check_their_outputs_before_the_work(monkeypatch, args, option, work):
    import importlib

    module, name = work.split(":")

    def must_not_run(*args, **kwargs):
        raise AssertionError("worked before checking the output")

    monkeypatch.setattr(importlib.import_module(module), name, must_not_run)
    code, _, err = run_cli(*args)
    assert code == 2 and option in one_line(err)
