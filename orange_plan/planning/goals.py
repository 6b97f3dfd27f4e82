"""Goals CSV: the points ``orange-plan reach --goals`` is asked about.

Format: a header row with columns ``x_m`` and ``y_m`` (map frame, metres) and optionally
``name``; one goal per row; other columns are ignored.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from orange_plan.errors import InputError
from orange_plan.files import csv_delimiter_hint, require_file


@dataclass(frozen=True)
class Goals:
    """Goals read from a CSV file.

    Attributes
    ----------
    xy_m : (n, 2) goal positions [m]
    names : one name per goal, or None where the file has no ``name`` column
    """

    xy_m: np.ndarray
    names: tuple[str | None, ...]


def load_goals(path: str | Path) -> Goals:
    """Read a goals CSV.

    Raises
    ------
    InputError
        Missing file, missing ``x_m``/``y_m`` column, no rows, or a non-numeric or non-finite
        coordinate (naming the row, counting the header as row 1).
    """
    path = Path(path)
    require_file(path, "goals")
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.DictReader(fh))
            header = rows[0].keys() if rows else []
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InputError(f"{path}: not a readable CSV file ({exc})") from None
    missing = [c for c in ("x_m", "y_m") if c not in header]
    if not rows:
        raise InputError(f"{path}: no goals (need a header with x_m, y_m and at least one row)")
    if missing:
        raise InputError(f"{path}: missing column(s) {', '.join(missing)} "
                         f"(have: {', '.join(h for h in header if h)})"
                         + csv_delimiter_hint(header))
    xy = np.empty((len(rows), 2))
    for i, row in enumerate(rows):
        for j, col in enumerate(("x_m", "y_m")):
            raw = row.get(col)
            try:
                value = float(raw)
            except (TypeError, ValueError):
                raise InputError(f"{path}: row {i + 2}: {col} = {raw!r} is not a number") from None
            if not math.isfinite(value):
                raise InputError(f"{path}: row {i + 2}: {col} = {raw!r} is not finite")
            xy[i, j] = value
    has_name = "name" in header
    names = tuple((row.get("name") or None) if has_name else None for row in rows)
    return Goals(xy, names)
