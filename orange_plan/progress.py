"""Progress displays for long commands: on stderr, only on a terminal, never with ``--json``.

Two shapes: ``stages`` for work made of a few named steps of unknown length (a spinner, the
step's name and the time elapsed) and ``bar`` for a known number of items. Both draw on the
rich console they are given (the CLI's stderr console, ``cli.progress_console``); without
one they show nothing, so library code can report progress with no display attached.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rich.console import Console


def wanted(as_json: bool) -> bool:
    """True when a progress display may be shown: stderr is a terminal and no ``--json``."""
    return not as_json and sys.stderr.isatty()


@contextmanager
def stages(console: Console | None) -> Iterator[Callable[[str], None]]:
    """Yield ``step(description)``; shows a transient spinner with the current step on
    ``console`` (nothing when None)."""
    if console is None:
        yield lambda description: None
        return
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    with Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(),
                  console=console, transient=True) as display:
        task = display.add_task("starting", total=None)
        yield lambda description: display.update(task, description=description)


@contextmanager
def bar(total: int, label: str,
        console: Console | None) -> Iterator[Callable[[], None] | None]:
    """Yield ``tick()`` advancing a transient bar of ``total`` items on ``console`` (None, and
    nothing shown, when ``console`` is None)."""
    if console is None:
        yield None
        return
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), TimeRemainingColumn(), console=console,
                  transient=True) as display:
        task = display.add_task(label, total=total)
        yield lambda: display.advance(task)
