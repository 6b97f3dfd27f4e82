"""Where the example scenarios and maps, and the real data sets, are: one look-up rule.

Every command that defaults a folder (``scenarios``, ``maps`` or ``data``) looks, in order, in

1. the working folder: ``./scenarios``, ``./maps``, ``./data`` (and for the data sets also
   ``../shared/data``, where a source checkout keeps them beside the repository);
2. the installed share folder: ``<prefix>/share/orange-plan/<kind>`` for the interpreter's
   prefix and the user base (``pip install .`` and ``pip install --user .`` put the examples
   there, ``scenarios/`` and ``maps/`` side by side so a scenario's ``map = "../maps/..."``
   still resolves; the data sets are not shipped, a user may put them there);
3. the source checkout the package is imported from (an editable install), the same names as 1.

A folder that is not found is reported with every place looked in.
"""

from __future__ import annotations

import site
import sys
from pathlib import Path

from orange_plan.errors import InputError

SHARE = ("share", "orange-plan")

CHECKOUT = Path(__file__).resolve().parents[1]
"""The folder holding the ``orange_plan`` package: a source checkout's root when it is one."""


def _near(folder: Path, kind: str) -> list[Path]:
    """``kind`` in ``folder``; the data sets also in ``../shared/data`` (a checkout's sibling)."""
    beside = [folder.parent / "shared" / "data"] if kind == "data" else []
    return [folder / kind, *beside]


def candidate_dirs(kind: str) -> list[Path]:
    """Folders that may hold ``kind`` (``scenarios``, ``maps`` or ``data``), in look-up order."""
    prefixes = [Path(sys.prefix), Path(site.getuserbase())]
    try:
        here = _near(Path.cwd(), kind)
    except FileNotFoundError:  # the working folder was deleted under us: nothing there
        here = []
    found = [*here, *(p.joinpath(*SHARE, kind) for p in prefixes), *_near(CHECKOUT, kind)]
    return list(dict.fromkeys(p.absolute() for p in found))  # once each, in order


def find_dir(kind: str) -> Path | None:
    """The first existing folder of ``candidate_dirs(kind)``, or None."""
    return next((folder for folder in candidate_dirs(kind) if folder.is_dir()), None)


def looked_in(kind: str) -> str:
    """Where ``find_dir(kind)`` looked, for a "not found" message."""
    return ", ".join(str(p) for p in candidate_dirs(kind))


def examples_dir(kind: str, option: str) -> Path:
    """``find_dir(kind)``, or an error naming where it looked and the option to give.

    Raises
    ------
    InputError
        No such folder: the message says where it looked and which option gives the folder.
    """
    folder = find_dir(kind)
    if folder is None:
        what = ("the real data sets (BorealTC, TUM BMW i3; not shipped with the package) are"
                if kind == "data" else f"the example {kind} folder is")
        raise InputError(f"{what} not found (looked in {looked_in(kind)}); give {option} DIR"
                         + (", the folder holding borealtc/ and tum_bmw_i3/" if kind == "data"
                            else f", e.g. the {kind}/ folder of the orange-plan source "
                                 "repository"))
    return folder
