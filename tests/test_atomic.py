"""Atomic writer: files get the user's umask, not mkstemp's 0600."""

from __future__ import annotations

import os
import stat

from orange_plan.atomic import atomic_path


def test_written_file_follows_umask(tmp_path):
    old = os.umask(0o022)
    try:
        target = tmp_path / "out.txt"
        with atomic_path(target) as tmp:
            tmp.write_text("x")
        assert stat.S_IMODE(target.stat().st_mode) == 0o644
        os.umask(0o077)
        with atomic_path(target) as tmp:
            tmp.write_text("y")
        assert stat.S_IMODE(target.stat().st_mode) == 0o600
    finally:
        os.umask(old)


def test_failed_write_leaves_previous_file(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    try:
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("boom")
    except RuntimeError:
        pass
    assert target.read_text() == "old"
    assert os.listdir(tmp_path) == ["out.txt"]
