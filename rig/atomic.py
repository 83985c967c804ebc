"""Files written whole or not at all.

:func:`write_atomic` writes to a temporary name in the destination's directory, flushes and (by
default) fsyncs it, then renames it over the final name: a rename within one file system is
atomic, so a reader (or a resumed run) sees the old file, the new one or none, never a part. The
data reach the disk before the rename that names them, so after a power loss a file that exists
is whole. A crash can leave a temporary behind: its name starts with ``.`` and holds
:data:`TEMP_MARK`, and :func:`sweep_temporaries` removes it on the next run. The directory entry
itself becomes durable with :func:`fsync_directory` (once per batch of files: a rename lost to a
power cut only costs the file, which a resumed run writes again).
"""

from __future__ import annotations

import contextlib
import itertools
import os
import threading
from pathlib import Path

__all__ = ["TEMP_MARK", "fsync_directory", "is_temporary", "sweep_temporaries", "write_atomic"]

TEMP_MARK = ".tmp-"
_counter = itertools.count()


def _temporary(path: Path) -> Path:
    """A name no other writer (process, thread, or an earlier call) uses at the same time."""
    return path.with_name(f".{path.name}{TEMP_MARK}{os.getpid()}-{threading.get_ident()}-{next(_counter)}")


def is_temporary(name: str) -> bool:
    """Whether a file name is one of :func:`write_atomic`'s temporaries."""
    return name.startswith(".") and TEMP_MARK in name


def write_atomic(path: str | Path, data: bytes | memoryview, *, fsync: bool = True) -> None:
    """Write ``data`` to ``path`` atomically (see the module doc). OSError as the OS raised it
    (ENOSPC on a full disk); the temporary is removed then."""
    path = Path(path)
    tmp = _temporary(path)
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            if fsync:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def fsync_directory(directory: str | Path) -> None:
    """Make the renames into ``directory`` durable (no-op where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some file systems refuse fsync on a directory; the files themselves are synced
    finally:
        os.close(fd)


def sweep_temporaries(directory: str | Path) -> int:
    """Remove the temporaries a crashed writer left in ``directory``; how many were removed."""
    removed = 0
    try:
        entries = list(os.scandir(directory))
    except FileNotFoundError:
        return 0
    for entry in entries:
        if is_temporary(entry.name) and entry.is_file(follow_symlinks=False):
            with contextlib.suppress(FileNotFoundError):
                os.unlink(entry.path)
                removed += 1
    return removed
