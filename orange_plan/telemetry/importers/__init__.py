"""Importers: robot logs and data sets -> the recording table of the recording format (docs/formats.md).

One module per format, each with ``read_<format>(path) -> pandas.DataFrame``. ``FORMATS``
maps the ``--format`` names to readers; ``guess_format`` picks one from the file.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pandas as pd

from orange_plan.errors import RecordingError
from orange_plan.telemetry.importers.borealtc import is_borealtc, read_borealtc
from orange_plan.telemetry.importers.rosbag import read_rosbag1, read_rosbag2
from orange_plan.telemetry.importers.tum_bmw_i3 import is_tum_bmw_i3, read_tum_bmw_i3
from orange_plan.telemetry.importers.ulog import read_ulog
from orange_plan.telemetry.importers.wadl import is_wadl, read_wadl

FORMATS: dict[str, Callable[[Path], pd.DataFrame]] = {
    "ulog": read_ulog,
    "rosbag1": read_rosbag1,
    "rosbag2": read_rosbag2,
    "borealtc": read_borealtc,
    "tum_bmw_i3": read_tum_bmw_i3,
    "wadl": read_wadl,
}
"""Format names accepted by ``orange-plan convert --format``."""

ULOG_MAGIC = b"ULog\x01\x12\x35"
ROSBAG1_MAGIC = b"#ROSBAG V2.0"
MCAP_MAGIC = b"\x89MCAP"
SQLITE_MAGIC = b"SQLite format 3\x00"


def allowed_formats() -> str:
    return ", ".join(FORMATS)


def guess_format(path: str | Path) -> str:
    """The format of a log, from its magic bytes, layout or name.

    Raises
    ------
    RecordingError
        The file does not exist or matches no format (the message lists the formats).
    """
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"{path}: no such file or folder")
    if path.is_dir():
        if (path / "metadata.yaml").exists():
            return "rosbag2"
        raise RecordingError(
            f"{path}: a folder but not a ROS 2 bag (no metadata.yaml); give --format, one of "
            f"{allowed_formats()}"
        )
    with open(path, "rb") as fh:
        head = fh.read(16)
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if head.startswith(ROSBAG1_MAGIC):
        return "rosbag1"
    if head.startswith(MCAP_MAGIC) or head.startswith(SQLITE_MAGIC):
        return "rosbag2"
    if is_borealtc(path):
        return "borealtc"
    if is_tum_bmw_i3(path):
        return "tum_bmw_i3"
    if is_wadl(path):
        return "wadl"
    raise RecordingError(
        f"{path}: cannot tell the log format; give --format, one of {allowed_formats()}"
    )


def read_log(path: str | Path, fmt: str | None = None) -> tuple[pd.DataFrame, str]:
    """Read a log with the named (or guessed) format: ``(frame, format)``.

    Raises
    ------
    RecordingError
        Unknown format name (the message lists the allowed ones) or an unreadable log.
    """
    path = Path(path)
    if fmt is None:
        fmt = guess_format(path)
    elif fmt not in FORMATS:
        raise RecordingError(f"unknown format '{fmt}'; allowed: {allowed_formats()}")
    if not path.exists():
        raise RecordingError(f"{path}: no such file or folder")
    return FORMATS[fmt](path), fmt


__all__ = ["FORMATS", "guess_format", "read_log"]
