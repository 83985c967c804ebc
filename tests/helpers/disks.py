"""A real full disk: a small tmpfs mounted for the length of a test (root only; the test is
skipped, saying why, where none can be mounted)."""

from __future__ import annotations

import os
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from tests.helpers.inputs import missing_input

__all__ = ["SmallDisk", "tmpfs_disk"]


@dataclass(frozen=True)
class SmallDisk:
    root: Path  # a directory with room for about ``size`` bytes
    size: int
    env: dict[str, str]  # environment a subprocess needs to see the same limit


def _mount_tmpfs(where: Path, size: int) -> str | None:
    """Mount a tmpfs of ``size`` bytes at ``where``; None, or why it could not be mounted."""
    if os.geteuid() != 0:
        return "mounting a tmpfs needs root"
    try:
        res = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", f"size={size},mode=0755", "rig-test-full-disk", str(where)],
            capture_output=True,
            text=True,
            timeout=30,
        )
    except (OSError, subprocess.TimeoutExpired) as err:
        return f"mount failed: {err}"
    return None if res.returncode == 0 else f"mount failed: {res.stderr.strip() or res.returncode}"


@contextmanager
def tmpfs_disk(where: Path, size: int) -> Iterator[SmallDisk]:
    """A real tmpfs of ``size`` bytes mounted at ``where``; skips the test if none can be mounted."""
    where.mkdir(parents=True)
    why = _mount_tmpfs(where, size)
    if why is not None:
        missing_input("a tmpfs mount", f"no real full disk here ({why})")
    try:
        yield SmallDisk(where, size, {})
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True, timeout=30)
