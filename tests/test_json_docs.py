"""docs/json.md lists every key each command's ``--json`` prints, and nothing it never prints.

Each command runs once on small inputs (the yard and world fixtures, a simulated recording,
the world with a WGS84 origin for export); the keys it prints, recursively (``energy.rated_J``,
``goals[].x_m``), are compared with the keys its section of docs/json.md lists, both ways.
A key marked ``*`` in the doc is conditional: it must be documented when printed, but an
output without it is not an error. ``<name>`` in the doc stands for any key at that level.
"""

from __future__ import annotations

import json
import re

import pytest
from conftest import REPO, run_cli, write_scenario
from logbuilders import write_ulog
from planning_worlds import write_world
from test_export import with_origin
from test_sweep import write_sweep

pytestmark = pytest.mark.timeout(300)

DOC = REPO / "docs" / "json.md"
ROUTE = "x_m,y_m\n1,1\n18,1\n18,4\n1,4\n1,1\n"


def printed_paths(obj, prefix: str = "") -> set[str]:
    """Every key path of a JSON value: ``a.b`` for objects, ``a[].b`` inside lists."""
    paths: set[str] = set()
    if isinstance(obj, dict):
        for key, value in obj.items():
            path = f"{prefix}.{key}" if prefix else key
            paths |= {path} | printed_paths(value, path)
    elif isinstance(obj, list):
        for item in obj:
            paths |= printed_paths(item, f"{prefix}[]")
    return paths


def documented(command: str) -> tuple[set[str], set[str]]:
    """(always, conditional) key paths of ``command``'s section: the backticked names of the
    first column of its key table; a ``*`` after a name marks it conditional."""
    text = DOC.read_text(encoding="utf-8")
    heading = re.search(rf"^##+ `orange-plan {re.escape(command)}[ `].*$", text, flags=re.M)
    assert heading, f"docs/json.md has no section for {command}"
    section = re.split(r"\n#{2,} ", text[heading.end():], maxsplit=1)[0]
    always, conditional = set(), set()
    for row in re.findall(r"^\| ([^|]+) \|", section, flags=re.M):
        for name, star in re.findall(r"`([^`]+)`(\\?\*)?", row):
            (conditional if star else always).add(name)
    assert always, f"docs/json.md: no keys listed for {command}"
    return always, conditional


def _matches(pattern: str, path: str) -> bool:
    """``path`` is the documented ``pattern``; ``<name>`` is any one key, and a pattern ending
    in one also covers what lies under that key."""
    regex = re.sub(r"<[^>]+>", r"[^.\\[\\]]+", re.escape(pattern))
    if pattern.endswith(">"):
        regex += r"(\..+|\[\].*)?"
    return re.fullmatch(regex, path) is not None


def compare(command: str, output: dict) -> None:
    always, conditional = documented(command)
    printed = printed_paths(output)
    patterns = always | conditional
    undocumented = sorted(p for p in printed if not any(_matches(d, p) for d in patterns))
    never = sorted(d for d in always if not any(_matches(d, p) for p in printed))
    assert not undocumented, f"{command} --json prints keys docs/json.md lacks: {undocumented}"
    assert not never, f"docs/json.md lists {command} keys never printed (mark them *): {never}"


def _json(*args) -> dict:
    code, out, err = run_cli(*args, "--json")
    assert code == 0, err
    return json.loads(out)


@pytest.fixture(scope="module")
def outputs(tmp_path_factory) -> dict[str, dict]:
    """One ``--json`` output per command, on small inputs."""
    d = tmp_path_factory.mktemp("json")
    world = with_origin(write_world(d, obstacles=[(10, 5, 14, 25)], time_limit_s=600.0))
    goals = d / "goals.csv"
    goals.write_text("x_m,y_m,name\n35,25,far\n12,10,in_box\n", encoding="utf-8")
    (d / "yard").mkdir()
    yard = write_scenario(d / "yard")
    (d / "route.csv").write_text(ROUTE, encoding="utf-8")
    rec = d / "rec.csv"
    out = {
        "range": _json("range", world),
        "plan": _json("plan", world, "-o", d / "plan.geojson", "--vertices", "300"),
        "reach": _json("reach", world, "--goals", goals, "--vertices", "200"),
        "simulate": _json("simulate", yard, d / "route.csv", "-o", rec, "--seed", "1",
                          "--to-depletion", "--max-duration-s", "300"),
    }
    out["predict"] = _json("predict", rec, "--scenario", yard, "--png", d / "p.png")
    out["calibrate"] = _json("calibrate", rec, "--scenario", yard, "-o", d / "fit.toml")
    out["diagnose"] = _json("diagnose", rec, "--scenario", yard, "-o", d / "diag.toml")
    out["convert"] = _json("convert", write_ulog(d / "drive.ulg"), "-o", d / "drive.csv")
    out["bench reach"] = _json("bench", "reach", world, "--repeats", "1", "--vertices", "200",
                               "--bitstar-s", "0")
    out["bench replan"] = _json("bench", "replan", world, "--replans", "2", "--vertices", "300")
    out["bench diagnose"] = _json("bench", "diagnose", "--seeds", "1", "--duration-s", "60",
                                  "--rate-hz", "1", "--only", "null-ground")
    out["bench concealed"] = _json("bench", "concealed", "--seeds", "1", "--duration-s", "60",
                                   "--rate-hz", "1", "--only", "null-ground")
    out["bench online"] = _json("bench", "online", "--seeds", "1", "--only", "rusti_v1_box")
    sweep = write_sweep(d / "yard", grid={"battery.rated_energy_Wh": [10.0]}, seeds=1)
    out["sweep"] = _json("sweep", sweep, "-o", d / "sweep.parquet", "--workers", "1")
    out["export"] = _json("export", d / "plan.geojson", "--scenario", world, "-o",
                          d / "plan.plan")
    out["check"] = _json("check", d / "plan.plan", "--scenario", world, "--wind", "2@90")
    out["bench check"] = _json("bench", "check", world, "--waypoints", "6", "--repeats", "1")
    return out


COMMANDS = ["range", "plan", "reach", "simulate", "convert", "predict", "calibrate", "diagnose",
            "export", "check", "bench check", "bench reach", "bench replan", "bench online", "bench diagnose",
            "bench concealed", "sweep"]


@pytest.mark.parametrize("command", COMMANDS)
def test_docs_list_exactly_the_printed_keys(outputs, command):
    compare(command, outputs[command])


COVERED_ELSEWHERE = {
    "bench plan": "test_bench_plan.py::test_cli_quick_json_with_a_standin_planner",
    "bench mission": "test_bench_mission.py::test_quick_run_completes_with_every_column",
    "bench sweep": "test_sweep.py::test_bench_sweep_small_run_meets_its_own_bookkeeping",
    "bench service": "test_bench_service.py::test_small_fleet_is_answered_in_full",
    "bench calibration": ("test_cli_simulate.py::"
                          "test_bench_calibration_reports_offline_and_online_on_real_runs"),
    "report paper": "test_report.py::test_reduced_report_is_complete_and_in_range",
    "bench flights": "test_wadl.py::test_bench_flights_runs_on_three_flights",
    "watch": ("test_watch.py::"
              "test_watch_sends_a_heavy_vehicle_home_in_time_and_without_it_the_vehicle_strands"),
    "fake-vehicle": ("test_watch.py::"
                     "test_a_px4_log_replayed_as_mavlink_is_watched_with_its_unknown_current_said"),
    "bench watch": "test_watch.py::test_bench_watch_measures_how_far_decisions_lag_the_telemetry",
}
"""Commands whose ``--json`` is costly to produce: the test that already runs each compares
its output with docs/json.md (``compare``) instead of running it again here."""


def cli_commands() -> dict[str, bool]:
    """Every command of the CLI (``"bench reach"``) -> whether it takes ``--json``."""
    import typer

    from orange_plan.cli import _register_commands, app

    _register_commands()

    def walk(command, path):
        subs = getattr(command, "commands", None)
        if subs is None:
            yield " ".join(path), any("--json" in getattr(p, "opts", ()) for p in command.params)
        for name, sub in (subs or {}).items():
            yield from walk(sub, (*path, name))

    return dict(walk(typer.main.get_command(app), ()))


def test_every_json_command_is_documented_and_checked():
    """A new command with ``--json`` needs its keys in docs/json.md and a test comparing them."""
    with_json = sorted(c for c, has_json in cli_commands().items() if has_json)
    for command in with_json:
        documented(command)  # fails when docs/json.md has no section for it
    unchecked = sorted(set(with_json) - set(COMMANDS) - set(COVERED_ELSEWHERE))
    assert not unchecked, f"--json outputs no test compares with docs/json.md: {unchecked}"


def test_every_command_has_a_user_page():
    """Every command is explained on some page of docs/ (besides its generated --help)."""
    pages = "\n".join(p.read_text(encoding="utf-8") for p in (REPO / "docs").rglob("*.md"))
    missing = sorted(c for c in cli_commands() if f"orange-plan {c}" not in pages)
    assert not missing, f"commands no page of docs/ mentions: {missing}"
