"""A small exception hierarchy.

``InputError`` is for anything the user supplied (files, arguments): the CLI prints its
message on one line and exits with code 2. ``OrangeError`` subclasses that are not input
errors are internal failures (exit code 1).
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable


class OrangeError(Exception):
    """Base class of every error raised on purpose by orange-plan."""


class InputError(OrangeError, ValueError):
    """Bad user input: a file, a value or an argument. The message names the problem."""


class ScenarioError(InputError):
    """A scenario TOML file is malformed or holds an out-of-range value."""


class MapError(InputError):
    """A map GeoJSON file (or its elevation raster) is malformed or inconsistent."""


class RecordingError(InputError):
    """A telemetry recording is malformed."""


class PlanningError(OrangeError):
    """The planner could not produce an answer (not caused by the input)."""


def close_match_hint(name: str, allowed: Iterable[str]) -> str:
    """Return ``" (did you mean 'x'?)"`` for the closest allowed name, or ``""``."""
    matches = difflib.get_close_matches(name, list(allowed), n=1, cutoff=0.6)
    return f" (did you mean '{matches[0]}'?)" if matches else ""
