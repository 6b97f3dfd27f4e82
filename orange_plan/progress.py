"""Progress displays for long commands: on stderr, only on a terminal, never with ``--json``.

Two shapes: ``stages`` for work made of a few named steps of unknown length (a spinner, the
step's name and the time elapsed) and ``bar`` for a known number of items.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager


def wanted(as_json: bool) -> bool:
    """True when a progress display may be shown: stderr is a terminal and no ``--json``."""
    return not as_json and sys.stderr.isatty()


@contextmanager
def stages(enabled: bool) -> Iterator[Callable[[str], None]]:
    """Yield ``step(description)``; shows a transient spinner with the current step."""
    if not enabled:
        yield lambda description: None
        return
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from orange_plan.cli import err

    with Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(),
                  console=err, transient=True) as display:
        task = display.add_task("starting", total=None)
        yield lambda description: display.update(task, description=description)


@contextmanager
def bar(total: int, label: str, enabled: bool) -> Iterator[Callable[[], None] | None]:
    """Yield ``tick()`` advancing a transient bar of ``total`` items (None when disabled)."""
    if not enabled:
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

    from orange_plan.cli import err

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), TimeRemainingColumn(), console=err,
                  transient=True) as display:
        task = display.add_task(label, total=total)
        yield lambda: display.advance(task)
