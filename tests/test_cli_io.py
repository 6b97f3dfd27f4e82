"""Output paths are checked up front (one reusable check), and the
CLI's own argument errors, CSV delimiters and folders-as-files give one line with exit 2."""

from __future__ import annotations

import subprocess
import sys

import pytest
from conftest import REPO, run_cli, write_scenario
from logbuilders import write_ulog

from orange_plan.errors import InputError
from orange_plan.files import check_output, csv_delimiter_hint, require_file

ROUTE = "x_m,y_m\n1,1\n18,1\n18,4\n1,4\n1,1\n"


def one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("orange-plan: error: ")
    return lines[0]


# --- item 3: outputs -------------------------------------------------------------------------
def test_convert_refuses_to_overwrite_its_input(tmp_path):
    log = write_ulog(tmp_path / "drive.ulg")
    before = log.read_bytes()
    code, _, err = run_cli("convert", log, "-o", log)
    assert code == 2 and "is also an input" in one_line(err)
    assert log.read_bytes() == before


def test_convert_refuses_to_overwrite_its_input_through_another_spelling(tmp_path):
    rec = tmp_path / "rec.csv"
    rec.write_text("t_s,power_W,v_mps\n0,1,0\n1,1,0\n", encoding="utf-8")
    code, _, err = run_cli("convert", rec, "--format", "borealtc", "-o",
                           tmp_path / "sub" / ".." / "rec.csv")
    assert code == 2 and "is also an input" in one_line(err)


@pytest.mark.parametrize("cmd", ["convert", "simulate", "predict", "reach", "calibrate"])
def test_unwritable_output_is_refused_up_front_naming_the_users_path(tmp_path, cmd):
    scenario = write_scenario(tmp_path)
    (tmp_path / "route.csv").write_text(ROUTE, encoding="utf-8")
    blocker = tmp_path / "file.txt"  # a file where the output's folder should be
    blocker.write_text("x", encoding="utf-8")
    rec = tmp_path / "rec.csv"
    rec.write_text("t_s,power_W,v_mps\n0,10,0.5\n1,10,0.5\n2,10,0.5\n", encoding="utf-8")
    target = blocker / ("out.png" if cmd in ("predict", "reach") else
                        "out.toml" if cmd == "calibrate" else "out.csv")
    args = {
        "convert": ["convert", write_ulog(tmp_path / "d.ulg"), "-o", target],
        "simulate": ["simulate", scenario, tmp_path / "route.csv", "-o", target],
        "predict": ["predict", rec, "--scenario", scenario, "--png", target],
        "reach": ["reach", scenario, "--png", target, "--vertices", "50"],
        "calibrate": ["calibrate", rec, "--scenario", scenario, "-o", target],
    }[cmd]
    code, stdout, err = run_cli(*args)
    line = one_line(err)
    assert code == 2 and str(target) in line and "cannot create" in line
    assert stdout == ""  # refused before any work was reported


def test_output_that_is_a_folder_is_refused(tmp_path):
    with pytest.raises(InputError, match="is a folder"):
        check_output(tmp_path, "-o")


def test_output_suffix_and_input_checks():
    with pytest.raises(InputError, match=r"--png a\.jpg: the file name must end in \.png"):
        check_output("a.jpg", "--png", [".png"])
    with pytest.raises(InputError, match="is also an input"):
        check_output("x/../b.csv", "-o", inputs=[None, "b.csv"])
    assert check_output("new/folder/b.csv", "-o").name == "b.csv"


def test_atomic_writer_names_the_users_path_not_the_temporary_file(tmp_path):
    from orange_plan.atomic import atomic_path

    blocker = tmp_path / "f"
    blocker.write_text("x", encoding="utf-8")
    with pytest.raises(InputError, match=r"f/out\.csv: cannot write") as info, \
            atomic_path(blocker / "out.csv"):
        pass
    assert ".out.csv." not in str(info.value)


# --- item 5: one line for every bad input ------------------------------------------------------
@pytest.mark.parametrize("args, needle", [
    (["range", "--bogus"], "range: No such option: --bogus"),
    (["range"], "range: Missing argument"),
    (["bench", "reach", "--repeats", "x"], "bench reach: Invalid value for '--repeats'"),
    (["nosuchcommand"], "No such command 'nosuchcommand'"),
])
def test_argument_errors_are_one_line_exit_2(args, needle):
    code, stdout, err = run_cli(*args)
    assert code == 2 and stdout == ""
    assert needle in one_line(err)


def test_argument_error_through_the_console_script_is_one_line():
    proc = subprocess.run([sys.executable, "-m", "orange_plan.cli", "range", "--bogus"],
                          capture_output=True, text=True, cwd=REPO, timeout=60)
    assert proc.returncode == 2 and "No such option" in one_line(proc.stderr)


def test_version_prints_without_a_command():
    code, stdout, _ = run_cli("--version")
    assert code == 0 and stdout.strip()


def test_semicolon_csv_gets_a_delimiter_hint(tmp_path):
    scenario = write_scenario(tmp_path)
    rec = tmp_path / "rec.csv"
    rec.write_text("t_s;power_W;v_mps\n0;10;0,5\n1;10;0,5\n", encoding="utf-8")
    code, _, err = run_cli("predict", rec, "--scenario", scenario)
    assert code == 2 and "separated by semicolons" in one_line(err)
    goals = tmp_path / "goals.csv"
    goals.write_text("x_m;y_m\n3;3\n", encoding="utf-8")
    code, _, err = run_cli("reach", scenario, "--goals", goals, "--vertices", "50")
    assert code == 2 and "separated by semicolons" in one_line(err)
    assert csv_delimiter_hint(["a", "b"]) == ""


@pytest.mark.parametrize("which", ["scenario", "recording", "route", "goals"])
def test_a_folder_given_as_a_file_says_so(tmp_path, which):
    scenario = write_scenario(tmp_path)
    folder = tmp_path / "adir.csv"
    folder.mkdir()
    args = {
        "scenario": ["range", tmp_path],
        "recording": ["predict", folder, "--scenario", scenario],
        "route": ["simulate", scenario, folder, "-o", tmp_path / "r.csv"],
        "goals": ["reach", scenario, "--goals", folder, "--vertices", "50"],
    }[which]
    code, _, err = run_cli(*args)
    assert code == 2 and "is a folder" in one_line(err)
    with pytest.raises(InputError, match="is a folder"):
        require_file(folder, which)


def test_calibrate_writes_into_a_new_folder_like_every_other_writer(tmp_path):
    from orange_plan.files import check_output  # the up-front check allows a new folder

    scenario = write_scenario(tmp_path)
    rec = tmp_path / "rec.csv"
    rows = "\n".join(f"{t},{10 + 0.1 * (t % 7)},{0.5 + 0.01 * (t % 5)}" for t in range(200))
    rec.write_text("t_s,power_W,v_mps\n" + rows + "\n", encoding="utf-8")
    target = tmp_path / "new" / "fitted.toml"
    check_output(target, "-o", [".toml"])
    code, _, err = run_cli("calibrate", rec, "--scenario", scenario, "-o", target,
                           "--terms", "ancillary")
    assert code == 0, err
    assert target.is_file()
