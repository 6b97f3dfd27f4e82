"""One check for every file a command writes (``-o``, ``--png``), run before the work.

A command that would fail only after minutes of work, or name a hidden temporary file, or
overwrite its own input, is refused up front with a one-line InputError naming the user's path.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from orange_plan.errors import InputError


def check_output(path: str | Path, option: str, suffixes: Iterable[str] = (),
                 inputs: Iterable[str | Path | None] = ()) -> Path:
    """Refuse an output path that cannot or must not be written.

    Parameters
    ----------
    path : the output file the user named
    option : the option that named it (``"-o"``, ``"--png"``), for the message
    suffixes : allowed endings (case-insensitive); empty: any
    inputs : files the command reads; writing over one of them is refused

    Returns
    -------
    Path
        ``path`` as a Path.

    Raises
    ------
    InputError
        The name has the wrong ending, is a folder, is one of the inputs, or its folder
        cannot be created or written.
    """
    path = Path(path)
    allowed = tuple(suffixes)
    if allowed and not path.name.lower().endswith(tuple(s.lower() for s in allowed)):
        raise InputError(f"{option} {path}: the file name must end in {' or '.join(allowed)}")
    if path.is_dir():
        raise InputError(f"{option} {path}: is a folder, not a file")
    for source in inputs:
        if source is not None and _same_file(path, Path(source)):
            raise InputError(f"{option} {path}: is also an input of this command; "
                             "write the output to another file")
    folder = _nearest_existing(path.parent)
    if not folder.is_dir():
        raise InputError(f"{option} {path}: cannot create it: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"{option} {path}: cannot write in folder {folder} (permission denied)")
    _probe_write(folder, path, option)
    if path.exists() and not os.access(path, os.W_OK):
        raise InputError(f"{option} {path}: the existing file is read-only")
    return path


def _probe_write(folder: Path, path: Path, option: str) -> None:
    """Create (and drop) a nameless file in ``folder``: permission bits do not tell everything
    (a superuser passes ``os.access`` on read-only mounts and pseudo file systems like /proc)."""
    import tempfile

    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise InputError(f"{option} {path}: cannot write in folder {folder} "
                         f"({exc.strerror or exc})") from None


def _same_file(a: Path, b: Path) -> bool:
    if a.exists() and b.exists():
        return os.path.samefile(a, b)
    return a.resolve() == b.resolve()


def _nearest_existing(folder: Path) -> Path:
    folder = folder.absolute()
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    return folder


def file_problem(path: Path, label: str, what: str) -> str | None:
    """Why ``path`` (written ``label`` where it was named) is not a readable ``what`` file,
    saying where it looked; None when it is a file."""
    if path.is_file():
        return None
    where = path.absolute()
    if path.is_dir():
        return f"'{label}' is a folder ({where}); give the {what} file itself"
    return f"'{label}' not found (looked for {where})"


def require_folder(path: Path, option: str) -> Path:
    """``path`` if it is a folder; else one InputError naming ``option``: a file where a folder
    is needed, or not found (with where it looked)."""
    if path.is_dir():
        return path
    if path.exists():
        raise InputError(f"{option} {path}: is a file; give a folder")
    raise InputError(f"{option} {path}: folder not found (looked for {path.absolute()})")


def require_file(path: str | Path, what: str, error: type[InputError] = InputError) -> Path:
    """Return ``path`` if it is an existing file; else one ``error`` line saying which:
    not found, or a folder where a file is needed."""
    path = Path(path)
    if path.is_dir():
        raise error(f"{path}: is a folder; give the {what} file itself")
    if not path.is_file():
        raise error(f"{path}: {what} file not found")
    return path


def csv_delimiter_hint(columns: Iterable[str]) -> str:
    """A hint when a CSV read as one column was separated by ``;`` or tabs, else ``""``."""
    columns = [str(c) for c in columns]
    if len(columns) == 1:
        for sep, name in ((";", "semicolons"), ("\t", "tabs")):
            if sep in columns[0]:
                return (f" (the header looks separated by {name}: orange-plan reads "
                        "comma-separated CSV with '.' as the decimal point)")
    return ""


def read_json(path: Path, what: str, error: type[InputError] = InputError):
    """Parse a JSON file; bad JSON, bad text or absurd nesting is one ``error`` line."""
    import json

    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise error(f"{path}: not a valid {what} file ({exc})") from None
    except RecursionError:
        raise error(f"{path}: not a valid {what} file (nested too deeply)") from None
