"""A small exception hierarchy.

``InputError`` is for anything the user supplied (files, arguments): the CLI prints its
message on one line and exits with code 2. ``OrangeError`` subclasses that are not input
errors are internal failures (exit code 1).
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Iterable, Mapping


class OrangeError(Exception):
    """Base class of every error raised on purpose by orange-plan.

    A message shows numbers as a person writes them: numpy 2's scalar repr
    (``np.float64(nan)``, from a ``{value!r}`` of a numpy value) is reduced to the value.
    """

    def __init__(self, *args):
        super().__init__(*(NUMPY_REPR.sub(r"\1", a) if isinstance(a, str) else a for a in args))


class InputError(OrangeError, ValueError):
    """Bad user input: a file, a value or an argument. The message names the problem."""


class NamedInputError(InputError):
    """Bad input whose message names a value the caller gave, which each interface names its
    own way: the CLI by its option (``--from``), the HTTP service by its field, the Python API
    by its argument (``start_xy``, what ``str()`` shows).

    Parameters
    ----------
    argument : the Python argument that holds the value (the key of ``named``'s mapping)
    template : the message, with ``{name}`` where the value's name goes
    """

    def __init__(self, argument: str, template: str):
        self.argument = argument
        self.template = template
        super().__init__(template.format(name=argument))

    def named(self, names: Mapping[str, str]) -> str:
        """The message with the value named by ``names[argument]`` (else the argument)."""
        return NUMPY_REPR.sub(r"\1", self.template.format(name=names.get(self.argument, self.argument)))


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


NUMPY_REPR = re.compile(r"\bnp\.(?:float|int|uint|complex|bool|str_|bytes_)\w*\((.*?)\)")
"""numpy 2's repr of a scalar (``np.float64(nan)``): a message shows the bare value."""


def plain_message(exc: BaseException | str) -> str:
    """One line for a person: whitespace collapsed, numpy's scalar wrappers dropped."""
    return NUMPY_REPR.sub(r"\1", " ".join(str(exc).split()))


def check_range(value: float | None, option: str, low: float = 0.0, high: float = math.inf,
                low_open: bool = True) -> None:
    """Refuse ``value`` (when given) outside ``(low, high]`` (``[low, high]`` with
    ``low_open=False``), naming the option; NaN and infinities are refused too."""
    if value is None:
        return
    above = value > low if low_open else value >= low
    if not (math.isfinite(value) and above and value <= high):
        bound = f"> {low:g}" if low_open else f">= {low:g}"
        limit = "" if high == math.inf else f" and <= {high:g}"
        raise InputError(f"{option} must be a number {bound}{limit}, got {value}")
