"""Parquet results of a sweep, one row per run id, written per finished run so a sweep resumes.

While a sweep runs, each finished run is one small Parquet file ``RESULTS.parquet.parts/ID.parquet``
written atomically by the client (never by a worker: a remote cluster needs no shared disk for
results). A kill loses at most the runs in flight. ``consolidate`` merges the parts into
``RESULTS.parquet`` (one row per id: a run that a killed worker had started may have finished
twice), then removes the parts.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterable
from pathlib import Path

import pandas as pd

from orange_plan.atomic import atomic_path
from orange_plan.errors import InputError


class ResultStore:
    """The results file of one sweep and its folder of per-run parts."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if self.path.suffix.lower() != ".parquet":
            raise InputError(f"-o {self.path}: the results file name must end in .parquet")
        self.parts = self.path.with_name(self.path.name + ".parts")

    def rows(self) -> pd.DataFrame:
        """Every stored row (results file and parts), one per run id, in sweep order."""
        frames = []
        if self.path.exists():
            frames.append(_read(self.path))
        if self.parts.is_dir():
            frames += [_read(p) for p in self.part_files()]
        frames = [f for f in frames if len(f)]
        if not frames:
            return pd.DataFrame({"run_id": pd.Series(dtype=str)})
        rows = pd.concat(frames, ignore_index=True)
        rows = rows.drop_duplicates("run_id", keep="first")
        return rows.sort_values("index", kind="stable").reset_index(drop=True)

    def part_files(self) -> list[Path]:
        """The finished runs' files (not a write a kill interrupted: hidden, see atomic_path)."""
        return sorted(self.parts.glob("[!.]*.parquet")) if self.parts.is_dir() else []

    def done_ids(self) -> set[str]:
        """Run ids already stored."""
        return set(self.rows()["run_id"])

    def check_belongs(self, run_ids: Iterable[str]) -> None:
        """Refuse a results file holding runs of another sweep (resuming would mix them)."""
        foreign = self.done_ids() - set(run_ids)
        if foreign:
            raise InputError(f"{self.path} holds {len(foreign)} run(s) that are not in this "
                             "sweep (another sweep, or the sweep file or a scenario changed); "
                             "write to another -o file or remove it")

    def add(self, row: dict) -> None:
        """Store one finished run (atomically: a kill leaves it whole or absent). A run
        stored already keeps its first row (its rerun has the same inputs)."""
        self.parts.mkdir(parents=True, exist_ok=True)
        part = self.parts / f"{row['run_id']}.parquet"
        if part.exists():
            return
        with atomic_path(part, suffix=".parquet") as tmp:
            pd.DataFrame([row]).to_parquet(tmp, index=False)

    def consolidate(self) -> pd.DataFrame:
        """Write every row, one per run id, to the results file; remove the parts."""
        rows = self.rows()
        with atomic_path(self.path, suffix=".parquet") as tmp:
            rows.to_parquet(tmp, index=False)
        if self.parts.is_dir():
            shutil.rmtree(self.parts)
        return rows


def _read(path: Path) -> pd.DataFrame:
    try:
        return pd.read_parquet(path)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable Parquet file ({exc})") from None
