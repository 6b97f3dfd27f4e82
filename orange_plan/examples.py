"""Where the example scenarios and maps are: a source checkout, or an installed package.

``pip install .`` installs them under ``<prefix>/share/orange-plan/`` (``scenarios/`` and
``maps/`` side by side, so a scenario's ``map = "../maps/..."`` still resolves); a checkout
has them at its root. The benchmarks use them as defaults.
"""

from __future__ import annotations

import site
import sys
from pathlib import Path

from orange_plan.errors import InputError

SHARE = ("share", "orange-plan")


def candidate_dirs(kind: str) -> list[Path]:
    """Folders that may hold the examples of ``kind`` (``scenarios`` or ``maps``), in order."""
    checkout = Path(__file__).resolve().parents[1]
    prefixes = [Path(sys.prefix), Path(site.getuserbase())]
    return [checkout / kind] + [p.joinpath(*SHARE, kind) for p in prefixes]


def examples_dir(kind: str, option: str) -> Path:
    """The first existing folder of ``candidate_dirs(kind)``.

    Raises
    ------
    InputError
        None exists: the message says which option gives the folder.
    """
    for folder in candidate_dirs(kind):
        if folder.is_dir():
            return folder
    raise InputError(f"the example {kind} folder is not installed here (looked in "
                     f"{', '.join(str(p) for p in candidate_dirs(kind))}); give {option} DIR, "
                     f"e.g. the {kind}/ folder of the orange-plan source repository")
