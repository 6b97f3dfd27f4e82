"""Telemetry: the recording table, its checks and importers from robot logs."""

from orange_plan.telemetry.recording import (
    DataIssue,
    Recording,
    integrate_J,
    load_recording,
    recording_from_frame,
    split_blocks,
    write_recording,
)
from orange_plan.telemetry.state import recording_state

__all__ = [
    "DataIssue",
    "Recording",
    "integrate_J",
    "load_recording",
    "recording_from_frame",
    "recording_state",
    "split_blocks",
    "write_recording",
]
