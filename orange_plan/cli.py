"""Command line: one command = parse, call one library function, print.

Bad input: one line on stderr, exit code 2. Internal failure: one line, exit code 1.
``--json`` prints exactly one JSON object on stdout.
"""

from __future__ import annotations

import contextlib
import functools
import json
import math
import sys
import warnings
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from typer.core import TyperGroup

try:  # typer >= 0.20 carries its own copy of click
    from typer._click import exceptions as click_exc
    from typer._click.globals import get_current_context
except ImportError:  # pragma: no cover - older typer runs on click itself
    from click import exceptions as click_exc
    from click.globals import get_current_context

from orange_plan import progress
from orange_plan.errors import (
    InputError,
    NamedInputError,
    OrangeError,
    plain_message,
)
from orange_plan.errors import (
    check_range as check_range,  # re-exported: every command's number check
)


class OneLineErrors(TyperGroup):
    """The root command group: the CLI's own argument errors (unknown option, missing
    argument, bad value) get the same one line and exit code 2 as every other bad input,
    instead of click/typer's multi-line box."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True,
             **extra):
        plain_help(self)
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, False, **extra)
        try:
            rv = super().main(args, prog_name, complete_var, False, **extra)
        except click_exc.NoArgsIsHelpError as exc:
            exc.show()
            sys.exit(exc.exit_code)
        except click_exc.UsageError as exc:
            fail(f"{_subcommand(exc.ctx)}{exc.format_message()} (see --help)", 2)
        except click_exc.ClickException as exc:
            fail(exc.format_message(), exc.exit_code)
        except typer.Abort:
            fail("aborted", 1)
        sys.exit(rv if isinstance(rv, int) else 0)


HELP_OPTION_NAMES = ["--help"]
"""The help option's name in every command (click's default; no command changes it)."""


def plain_help(command) -> None:
    """Make ``command``'s help, and its subcommands', print as written.

    Help texts are plain text, not rich markup: a unit such as ``[s]`` (strike-through in
    rich markup) or ``[Hz]`` would otherwise vanish, so every bracket is escaped here, once,
    for every option, argument and docstring. A boolean flag takes no value, so it is shown
    without typer's ``<bool>`` type label.
    """
    from types import SimpleNamespace

    from rich.markup import escape

    if getattr(command, "_plain_help", False):
        return
    command._plain_help = True
    if command.help:
        command.help = escape(command.help)
    helper = command.get_help_option(SimpleNamespace(help_option_names=HELP_OPTION_NAMES))
    for param in [*command.params, *([helper] if helper is not None else [])]:
        if getattr(param, "help", None):
            param.help = escape(param.help)
        if getattr(param, "is_flag", False):
            param.metavar = ""
    for sub in getattr(command, "commands", {}).values():
        plain_help(sub)


def _subcommand(ctx) -> str:
    """``"bench reach: "`` for an error inside a subcommand, ``""`` at the root."""
    names = []
    while ctx is not None and ctx.parent is not None:
        names.append(ctx.info_name)
        ctx = ctx.parent
    return " ".join(reversed(names)) + ": " if names else ""


app = typer.Typer(
    cls=OneLineErrors,
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="ORangE mission planner: operational range, reachability and energy-aware plans.",
)


class WholeWhenPiped(Console):
    """A console that, when its output is not a terminal (a pipe, a file, a test runner),
    widens itself to each printed table's natural width: a number is never cut to ``100.…``
    or wrapped because an unknown terminal is assumed 80 columns wide. On a terminal it
    behaves as rich does (fits the window).

    A width given to the constructor is kept as given. A ``COLUMNS`` variable in the
    environment is only the narrowest a piped table is printed: it describes a terminal, and
    a parent process may export it without one (GNU readline sets ``COLUMNS=80`` in the
    environment of every program it loads in, and their children inherit it)."""

    def __init__(self, *, width: int | None = None, **kwargs) -> None:
        super().__init__(width=width, **kwargs)
        self._width_given = width is not None
        self._widening = False

    def print(self, *objects, **kwargs) -> None:
        if self.is_terminal or self._width_given or self._widening:
            super().print(*objects, **kwargs)
            return
        from rich.measure import Measurement

        wide = self.options.update(width=PIPED_MAX_WIDTH)
        natural = max((Measurement.get(self, wide, o).maximum for o in objects
                       if not isinstance(o, str)), default=0)
        narrowest = self._width
        self._width = max(self.size.width, natural)
        self._widening = True
        try:
            super().print(*objects, **kwargs)
        finally:
            self._width = narrowest
            self._widening = False


PIPED_MAX_WIDTH = 1000
"""Widest a table is printed when the output is not a terminal [characters]."""

out = WholeWhenPiped()
err = WholeWhenPiped(stderr=True)



def progress_console(as_json: bool) -> Console | None:
    """The console a command's progress display draws on: stderr when it is a terminal and
    no ``--json`` was asked for, else None (no display)."""
    return err if progress.wanted(as_json) else None


JsonOpt = Annotated[bool, typer.Option("--json", help="Print one JSON object on stdout.")]
SCENARIO_HELP = ("Scenario TOML file (robot, losses, battery, ancillary, mission, environment; "
                 "names its map).")
RECORDING_HELP = ("Recording file(s), .csv or .parquet: t_s, power_W (or voltage_V and "
                  "current_A), x_m and y_m (or v_mps).")
ScenarioArg = Annotated[Path, typer.Argument(help=SCENARIO_HELP)]
bench_app = typer.Typer(no_args_is_help=True, help="Benchmarks (timings are medians).")
app.add_typer(bench_app, name="bench")
"""The ``bench`` command group; the command modules named ``bench*`` register on it."""


# --- argument helpers shared by several commands ---


def parse_xy(text: str, option: str) -> tuple[float, float]:
    """``"X,Y"`` -> (x, y) in metres; InputError naming the option otherwise."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        x, y = (float(p) for p in parts)
    except ValueError:
        raise InputError(f"{option} must be X,Y in metres (e.g. 120,45.5), got {text!r}") from None
    if not all(map(lambda v: v == v and abs(v) != float("inf"), (x, y))):
        raise InputError(f"{option} must be finite, got {text!r}")
    return x, y


SEED_MAX = 2**32 - 1
"""Largest seed: the random generators behind --seed (numpy's legacy seeding, the roadmap
sampler) take unsigned 32-bit seeds."""
INT_MAX = 2**63 - 1
"""Largest integer any count option may hold (a 64-bit array index)."""
MAX_TIME_S = 1e9
"""Longest mission time an option may give [s] (about 32 years: beyond any battery's life,
so a larger number is a slip of units, not a mission)."""
MAX_GRADE_WINDOW_M = 1e5
"""Longest elevation smoothing window [m] (100 km: longer than any map's drive)."""


def check_numbers(values: dict) -> None:
    """Refuse, naming the option, a number no command can use: a float option that is NaN or
    infinite, a seed outside 0..SEED_MAX, an integer beyond 64 bits.

    Parameters
    ----------
    values : the command's keyword arguments (parameter name -> parsed value)

    Raises
    ------
    InputError
        The first such value.
    """
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            continue
        if isinstance(value, float) and not math.isfinite(value):
            raise InputError(f"{option_name(name)} must be a finite number, got {value}")
        if name == "seed" and not 0 <= value <= SEED_MAX:
            raise InputError(f"{option_name(name)} must be a whole number from 0 to "
                             f"{SEED_MAX}, got {value}")
        if isinstance(value, int) and abs(value) > INT_MAX:
            raise InputError(f"{option_name(name)} = {value} is too large")


def option_name(param: str) -> str:
    """The option that sets the command parameter ``param`` (``time_s`` -> ``--time-s``)."""
    ctx = get_current_context(silent=True)
    for p in getattr(getattr(ctx, "command", None), "params", ()):
        if p.name == param and p.opts:
            return max(p.opts, key=len)
    return "--" + param.replace("_", "-")


def default_scenario() -> Path:
    """The hilly example shipped with the package (scenarios/kiwibot_campus.toml)."""
    from orange_plan.examples import examples_dir

    return examples_dir("scenarios", "a SCENARIO argument") / "kiwibot_campus.toml"


OPTION_NAMES = {"start_xy": "--from", "energy_used_J": "--energy-used-J",
                "time_used_s": "--time-used-s"}
"""The CLI option that gives each value a ``NamedInputError`` may name."""


class CommandFailed(SystemExit):
    """Raised after the error line has been printed."""


def fail(message: str, code: int) -> None:
    """Print one line on stderr and exit with ``code``."""
    first_line = plain_message(message)
    print(f"orange-plan: error: {first_line}", file=sys.stderr)
    raise CommandFailed(code)


def handles_errors(fn):
    """Turn InputError into exit 2 and other failures into exit 1, one line each.

    Before the command runs, numbers no command can use (NaN, infinities, seeds out of
    range) are refused naming their option (``check_numbers``).

    Library warnings become one ``orange-plan: warning: ...`` line each instead of a raw
    traceback-style block. With ``--json``, whatever a library prints on stdout goes to
    stderr, so stdout holds the JSON object alone.
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        json_mode = bool(kwargs.get("as_json"))
        try:
            check_numbers(kwargs)
            with _one_line_warnings(), _stdout_for_json(json_mode):
                return fn(*args, **kwargs)
        except NamedInputError as exc:
            fail(exc.named(OPTION_NAMES), 2)
        except InputError as exc:
            fail(str(exc), 2)
        except OrangeError as exc:
            fail(str(exc), 1)
        except (typer.Exit, typer.Abort, SystemExit):
            raise
        except Exception as exc:  # noqa: BLE001 - an internal failure is still one clear line
            fail(f"internal error: {type(exc).__name__}: {exc}", 1)

    return wrapper


_json_stream: list = []
"""The real stdout while a ``--json`` command runs with library prints sent to stderr."""


@contextlib.contextmanager
def _stdout_for_json(enabled: bool):
    if not enabled:
        yield
        return
    _json_stream.append(sys.stdout)
    try:
        with contextlib.redirect_stdout(sys.stderr):
            yield
    finally:
        _json_stream.pop()


@contextlib.contextmanager
def _one_line_warnings():
    with warnings.catch_warnings(record=True) as caught:
        try:
            yield
        finally:
            for message in dict.fromkeys(
                    f"{w.category.__name__}: {w.message}" for w in caught):
                print(f"orange-plan: warning: {' '.join(message.split())}", file=sys.stderr)


def warn(message: str) -> None:
    """One ``orange-plan: warning: ...`` line on stderr (also under --json: stdout stays one
    object), in the form library warnings take."""
    print(f"orange-plan: warning: {' '.join(str(message).split())}", file=sys.stderr)


def print_json(obj) -> None:
    """Print one JSON object (NaN/inf become null: JSON has no such numbers)."""
    stream = _json_stream[-1] if _json_stream else out.file
    stream.write(json.dumps(_finite(obj), indent=2) + "\n")


def _finite(obj):
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def _print_version(value: bool) -> None:
    if value:
        from orange_plan import __version__

        out.print(__version__)
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option(
        "--version", help="Print the version and exit.", callback=_print_version,
        is_eager=True)] = False,
) -> None:
    """ORangE mission planner for battery-powered robots (ground, aerial, marine)."""


def main() -> None:
    """Console-script entry point."""
    _register_commands()
    app()


def _register_commands() -> None:
    """Import the command modules; each registers its command(s) on ``app``."""
    import importlib

    for name in COMMAND_MODULES:
        importlib.import_module(f"orange_plan.commands.{name}")


COMMAND_MODULES = [
    "range_", "plan", "reach", "simulate", "convert", "predict", "calibrate", "diagnose", "bench",
    "bench_identify", "bench_replan", "bench_sweep", "bench_concealed", "bench_diagnose", "export",
    "check", "bench_check", "serve", "report", "sweep", "bench_flights", "watch", "fake_vehicle",
    "bench_watch",
]
"""One module per command in orange_plan/commands/, registered in this order."""


if __name__ == "__main__":
    # ``python -m orange_plan.cli`` runs this file as __main__, a second copy of the module;
    # the command modules register on the importable orange_plan.cli's app, so run that one.
    from orange_plan.cli import main as _main

    _main()
