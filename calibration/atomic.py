"""Files written whole or not at all: the one way every package writes a file in place
(calibration files, ``rig process`` outputs, LUT cache entries, recordings' metadata, reports).
It lives in ``calibration``, the bottom layer, so that every package above can use it.

:func:`atomic_file` (and :func:`write_atomic`, for data in hand) writes to a temporary name in the
destination's directory, flushes and (by default) fsyncs it, gives it the permissions of the file
it replaces, then renames it over the final name: a rename within one file system is atomic, so a
reader (or a resumed run) sees the old file, the new one or none, never a part. The data reach the
disk before the rename that names them, so after a power loss a file that exists is whole. A
crash can leave a temporary behind: its name starts with ``.`` and holds :data:`TEMP_MARK`, and
:func:`sweep_temporaries` removes it on the next run. The directory entry itself becomes durable
with :func:`fsync_directory` (once per batch of files: a rename lost to a power cut only costs the
file, which a resumed run writes again).

:func:`atomic_directory` does the same for a directory built in one go (a rendered recording of
the demo or a benchmark): built under ``.NAME.tmp-PID``, renamed into place when complete; builds
racing in several processes leave the first one's, and a dead process's leftovers are removed.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import shutil
import stat
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO

__all__ = [
    "TEMP_MARK",
    "atomic_directory",
    "atomic_file",
    "fsync_directory",
    "is_temporary",
    "sweep_temporaries",
    "write_atomic",
]

TEMP_MARK = ".tmp-"
_counter = itertools.count()


def _temporary(path: Path) -> Path:
    """A name no other writer (process, thread, or an earlier call) uses at the same time."""
    return path.with_name(f".{path.name}{TEMP_MARK}{os.getpid()}-{threading.get_ident()}-{next(_counter)}")


def is_temporary(name: str) -> bool:
    """Whether a file name is one of :func:`atomic_file`'s temporaries."""
    return name.startswith(".") and TEMP_MARK in name


def _keep_mode(path: Path, tmp: Path) -> None:
    """Give ``tmp`` the permissions of the file it replaces (a new file keeps the umask's)."""
    try:
        mode = stat.S_IMODE(os.stat(path).st_mode)
    except FileNotFoundError:
        return
    os.chmod(tmp, mode)


@contextlib.contextmanager
def atomic_file(path: str | Path, *, fsync: bool = True) -> Iterator[BinaryIO]:
    """A binary file to write ``path``'s new content into (see the module doc): when the block
    ends without an error it is flushed, fsynced (``fsync``) and renamed over ``path``; on an
    error, the OS's (ENOSPC on a full disk) or the block's, the temporary is removed and ``path``
    is left as it was."""
    path = Path(path)
    tmp = _temporary(path)
    try:
        with open(tmp, "wb") as f:
            yield f
            f.flush()
            if fsync:
                os.fsync(f.fileno())
        _keep_mode(path, tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_atomic(path: str | Path, data: bytes | memoryview, *, fsync: bool = True) -> None:
    """Write ``data`` to ``path`` atomically (:func:`atomic_file`). OSError as the OS raised it."""
    with atomic_file(path, fsync=fsync) as f:
        f.write(data)


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


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's: alive
    return True


def _remove_dead_builds(path: Path) -> None:
    """The temporary directories of ``path`` left by builds whose process is gone."""
    for tmp in path.parent.glob(f".{path.name}{TEMP_MARK}*"):
        try:
            pid = int(tmp.name.rsplit("-", 1)[1])
        except ValueError:
            pid = -1
        if pid != os.getpid() and not _process_alive(pid):
            shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def atomic_directory(path: str | Path, *, complete: Callable[[Path], bool]) -> Iterator[Path]:
    """A new, empty directory to build ``path`` in (``.NAME.tmp-PID`` beside it, after removing
    what dead builds of ``path`` left), renamed to ``path`` when the block ends without an error.
    When another process's build got there first the rename fails: this build is dropped if
    ``complete(path)`` says that one is whole, else the OSError is raised. The temporary is gone
    afterwards in every case."""
    path = Path(path)
    _remove_dead_builds(path)
    tmp = path.with_name(f".{path.name}{TEMP_MARK}{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        yield tmp
        try:
            os.rename(tmp, path)
        except OSError:
            if not complete(path):
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
