"""Command line: one command = parse, call one library function, print (SPEC §5).

Bad input: one line on stderr, exit code 2. Internal failure: one line, exit code 1.
``--json`` prints exactly one JSON object on stdout.
"""

from __future__ import annotations

import functools
import json
import math
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from orange_plan.errors import InputError, OrangeError

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="ORangE mission planner: operational range, reachability and energy-aware plans.",
)
out = Console()
err = Console(stderr=True)

JsonOpt = Annotated[bool, typer.Option("--json", help="Print one JSON object on stdout.")]
ScenarioArg = Annotated[Path, typer.Argument(help="Scenario TOML file (SPEC §2).")]


class CommandFailed(SystemExit):
    """Raised after the error line has been printed."""


def fail(message: str, code: int) -> None:
    """Print one line on stderr and exit with ``code``."""
    first_line = " ".join(str(message).split())
    print(f"orange-plan: error: {first_line}", file=sys.stderr)
    raise CommandFailed(code)


def handles_errors(fn):
    """Turn InputError into exit 2 and other failures into exit 1, one line each."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except InputError as exc:
            fail(str(exc), 2)
        except OrangeError as exc:
            fail(str(exc), 1)
        except (typer.Exit, typer.Abort, SystemExit):
            raise
        except Exception as exc:  # noqa: BLE001 - an internal failure is still one clear line
            fail(f"internal error: {type(exc).__name__}: {exc}", 1)

    return wrapper


def print_json(obj) -> None:
    """Print one JSON object (NaN/inf become null: JSON has no such numbers)."""
    out.file.write(json.dumps(_finite(obj), indent=2) + "\n")


def _finite(obj):
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", help="Print the version and exit.")] = False,
) -> None:
    """ORangE mission planner for battery-powered robots (ground, aerial, marine)."""
    if version:
        from orange_plan import __version__

        out.print(__version__)
        raise typer.Exit()


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
    "range_", "plan", "reach", "simulate", "convert", "predict", "calibrate", "bench",
    "bench_identify", "export", "serve",
]
"""One module per command in orange_plan/commands/, registered in this order."""


if __name__ == "__main__":
    # ``python -m orange_plan.cli`` runs this file as __main__, a second copy of the module;
    # the command modules register on the importable orange_plan.cli's app, so run that one.
    from orange_plan.cli import main as _main

    _main()
