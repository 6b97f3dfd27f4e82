"""What the CLI prints for people: whole numbers in tables when the output is not a terminal,
and ``--help`` that shows every unit bracket as written and flags without a value label."""

from __future__ import annotations

import io
import json
import re

import pytest
from conftest import run_cli
from planning_worlds import write_world
from rich.table import Table

import orange_plan.cli as cli

pytestmark = pytest.mark.timeout(120)


def twelve_numbers() -> Table:
    """A table wider than 80 columns: twelve numbers with six decimals under long headings."""
    table = Table()
    for i in range(12):
        table.add_column(f"column {i}", justify="right")
    table.add_row(*[f"100.{i:06d}" for i in range(12)])
    return table


def test_a_piped_table_prints_every_value_whole():
    screen = io.StringIO()
    console = cli.WholeWhenPiped(file=screen)
    table = twelve_numbers()
    console.print(table)
    text = screen.getvalue()
    assert "…" not in text
    assert all(f"100.{i:06d}" in text for i in range(12))


def test_an_exported_columns_is_the_narrowest_a_piped_table_is_printed(monkeypatch):
    """A parent process may export COLUMNS without a terminal (GNU readline sets 80, and
    pytest's xdist workers inherit it): piped tables still print whole, at least that wide."""
    monkeypatch.setenv("COLUMNS", "80")
    monkeypatch.setenv("LINES", "24")
    screen = io.StringIO()
    console = cli.WholeWhenPiped(file=screen)
    table = twelve_numbers()
    console.print(table)
    console.print("short")
    lines = screen.getvalue().splitlines()
    assert "…" not in screen.getvalue()
    assert all(f"100.{i:06d}" in screen.getvalue() for i in range(12))
    assert console.width == 80 and lines[-1] == "short"


def test_a_width_given_to_the_console_is_kept():
    screen = io.StringIO()
    console = cli.WholeWhenPiped(file=screen, width=40)
    table = Table()
    table.add_column("a long column heading", justify="right")
    table.add_column("another long column heading", justify="right")
    table.add_row("100.000001", "100.000002")
    console.print(table)
    assert max(len(line) for line in screen.getvalue().splitlines()) <= 40


def test_reach_goal_table_keeps_every_number_whole(tmp_path):
    scenario = write_world(tmp_path, obstacles=[(10, 5, 14, 25)])
    goals = tmp_path / "goals.csv"
    long_name = "the_north_east_corner_of_the_yard_beyond_the_container_stack"
    goals.write_text(f"x_m,y_m,name\n35.125,25.875,{long_name}\n12,10,in_box\n",
                     encoding="utf-8")
    args = ("reach", scenario, "--goals", goals, "--vertices", "200")
    code, text, err = run_cli(*args)
    assert code == 0, err
    report = json.loads(run_cli(*args, "--json")[1])
    assert "…" not in text and long_name in text
    for goal in report["goals"]:
        assert f"{goal['x_m']:g}" in text and f"{goal['y_m']:g}" in text
        if goal["margin_J"] is not None:
            assert f"{goal['margin_J'] / 1e3:,.2f}" in text
        if goal.get("reason"):
            assert " ".join(goal["reason"].split()) in text


def _command_paths(group, prefix=()):
    """Every command path of the CLI: ("range",), ("bench", "reach"), ..."""
    for name, command in group.commands.items():
        if hasattr(command, "commands"):
            yield (*prefix, name), command
            yield from _command_paths(command, (*prefix, name))
        else:
            yield (*prefix, name), command


def _raw_help_brackets(command) -> set[str]:
    """The ``[...]`` written in a command's docstring and its options' help texts."""
    texts = [command.help or ""] + [getattr(p, "help", None) or "" for p in command.params]
    return {m for t in texts for m in re.findall(r"\[[^\[\]]+\]", " ".join(t.split()))}


def _flat(help_text: str) -> str:
    """The help screen as one line: box drawing gone, whitespace collapsed."""
    return " ".join(re.sub(r"[│╭╮╰╯─]", " ", help_text).split())


def _all_commands():
    import typer.main

    cli._register_commands()
    return list(_command_paths(typer.main.get_command(cli.app)))


@pytest.mark.parametrize("path, command", _all_commands(), ids=lambda v: " ".join(v)
                         if isinstance(v, tuple) else "")
def test_help_shows_unit_brackets_and_plain_flags(path, command):
    code, text, err = run_cli(*path, "--help")
    assert code == 0, err
    flat = _flat(text)
    missing = [b for b in _raw_help_brackets(command) if b not in flat]
    assert not missing, f"{' '.join(path)} --help lost {missing}"
    assert "<bool>" not in text


def test_some_help_texts_carry_units():
    """The check above is not empty: the unit brackets it looks for exist."""
    found = set().union(*(_raw_help_brackets(c) for _, c in _all_commands()))
    assert {"[s]", "[J]", "[Hz]", "[bytes]"} <= found
