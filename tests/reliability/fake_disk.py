"""A byte budget for the files ``rig.recording`` opens under one directory: the injected form of
a full disk (ENOSPC after a short write), for machines where no tmpfs can be mounted."""

from __future__ import annotations

import builtins
import errno
import io
import os
from pathlib import Path
from typing import Any

__all__ = ["Budget", "install", "limited_open"]


class Budget:
    """Bytes left on the fake disk, shared by every file it wraps; None = unlimited (a test may
    set ``remaining`` when the disk should fill)."""

    def __init__(self, remaining: int | None = None) -> None:
        self.remaining = remaining

    def take(self, n: int) -> int:
        if self.remaining is None:
            return n
        if self.remaining <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        k = min(n, self.remaining)
        self.remaining -= k
        return k


class _LimitedFile:
    """A real file whose writes draw on the budget: an unbuffered file returns a short count
    (the caller retries and gets ENOSPC), a buffered one writes what fits, then raises."""

    def __init__(self, f: Any, budget: Budget) -> None:
        self._f, self._budget = f, budget

    def write(self, data: bytes | memoryview) -> int:
        data = bytes(data)
        k = self._budget.take(len(data))
        self._f.write(data[:k])
        if k < len(data):
            if isinstance(self._f, io.FileIO):
                return k
            self._f.flush()
            raise OSError(errno.ENOSPC, "No space left on device")
        return k

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)

    def __enter__(self) -> _LimitedFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self._f.close()


def limited_open(root: str | Path, budget: Budget | int) -> Any:
    """An ``open`` whose files opened for writing under ``root`` share ``budget`` (bytes)."""
    base = os.path.realpath(root)
    if isinstance(budget, int):
        budget = Budget(budget)
    real_open = builtins.open

    def opener(file: Any, mode: str = "r", *args: Any, **kw: Any) -> Any:
        f = real_open(file, mode, *args, **kw)
        inside = os.path.realpath(os.fspath(file)).startswith(base + os.sep)
        return _LimitedFile(f, budget) if inside and ("w" in mode or "a" in mode) else f

    return opener


def install(root: str | Path, budget_bytes: int) -> None:
    """Route rig.recording's ``open`` through :func:`limited_open` (for a whole subprocess)."""
    import rig.recording

    rig.recording.open = limited_open(root, budget_bytes)  # type: ignore[attr-defined]
