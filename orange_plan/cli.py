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
from rich.table import Table

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
        except Exception as exc:  # an internal failure must still be one clear line
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


@app.command("range")
@handles_errors
def range_cmd(scenario: ScenarioArg, as_json: JsonOpt = False) -> None:
    """Operational range: d_max, v_opt and where the energy goes (Eq. 3, 4, 6, 11)."""
    from orange_plan.context import load_context
    from orange_plan.physics.range import range_report

    report = range_report(load_context(scenario))
    if as_json:
        print_json(report.to_dict())
        return
    out.print(_range_table(report))


def _range_table(report) -> Table:
    e, s, g = report.energy, report.simplified, report.generalised
    table = Table(title=f"Operational range: {report.scenario} ({report.robot_kind})",
                  show_header=True, header_style="bold")
    table.add_column("quantity")
    table.add_column("value", justify="right")
    table.add_column("note")
    rows = [
        ("d_max", f"{s.d_max_m:,.1f} m", f"simplified ORangE, Eq. 6, flat ground crr={report.crr:g}"),
        ("v_opt", f"{s.v_opt_mps:.3f} m/s", "speed in \\[v_min, v_max] maximising range"),
        ("mission time", f"{s.mission_time_s / 60:,.1f} min", "stops included (duty cycle)"),
        ("energy per metre", f"{s.energy_per_m_J:,.2f} J/m", ""),
        ("d_max (generalised)", f"{g.d_max_m:,.1f} m",
         f"offline Eq. 11 over the map at {g.v_opt_mps:.3f} m/s (wind, grades, surfaces)"),
        ("", "", ""),
        ("rated energy", f"{e.rated_J / 1e3:,.2f} kJ", "E_O"),
        ("capacity decay", f"{e.decay_J / 1e3:,.2f} kJ", "Eq. 3: cycles and age"),
        ("battery loss eta_1", f"{e.battery_loss_eta1_J / 1e3:,.2f} kJ", "self-discharge"),
        ("available", f"{e.available_J / 1e3:,.2f} kJ", "E_avail = ancillary + traversal"),
        ("  ancillary", f"{e.ancillary_J / 1e3:,.2f} kJ",
         f"P_anc = {report.ancillary_power_W:.2f} W for the mission time"),
        ("    ancillary loss eta_4", f"{e.ancillary_loss_eta4_J / 1e3:,.2f} kJ", ""),
        ("  traversal", f"{e.traversal_J / 1e3:,.2f} kJ", f"ME / Omega, Omega = {report.omega:.3f}"),
        ("    motor loss eta_2", f"{e.motor_loss_eta2_J / 1e3:,.2f} kJ", ""),
        ("    mechanical loss eta_3", f"{e.mechanical_loss_eta3_J / 1e3:,.2f} kJ", ""),
        ("    mechanical work", f"{e.mechanical_work_J / 1e3:,.2f} kJ", "rolling + drag (ME)"),
    ]
    for row in rows:
        table.add_row(*row)
    return table


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":
    main()
