"""Inputs that every test worker of a run reads the same: made once per run, not once per worker.

Under pytest-xdist each worker has its own base temporary directory, under one directory of the
run (:func:`run_root`); :func:`made_once` makes a file or directory there under a lock (the first
worker to ask makes it, the others wait for it and read it). Without xdist the run's directory
is the session's own. :func:`once_per_run` does the same for a function's results (renders
that several test modules ask for with the same arguments), once the tests' conftest has said
where (:func:`share_under`)."""

from __future__ import annotations

import fcntl
import functools
import hashlib
import os
import pickle
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import pytest

__all__ = ["made_once", "once_per_run", "run_root", "share_under"]

R = TypeVar("R")
_root: Path | None = None


def run_root(factory: pytest.TempPathFactory) -> Path:
    """The directory every worker of this test run shares."""
    base = factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def made_once(root: Path, name: str, make: Callable[[Path], object]) -> Path:
    """``root/name``, made by ``make(root/name)`` once per test run (see the module doc).
    Readers must not change it: other workers read it too."""
    out = root / f"shared-{name}"
    done = root / f"shared-{name}.done"
    with (root / f"shared-{name}.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not done.is_file():
            if out.is_dir():  # a worker that failed half-way
                shutil.rmtree(out)
            out.unlink(missing_ok=True)
            make(out)
            done.touch()
    return out


def share_under(root: Path | None) -> None:
    """Keep :func:`once_per_run` results under ``root`` (None: each process computes its own)."""
    global _root
    _root = root


def once_per_run(fn: Callable[..., R]) -> Callable[..., R]:
    """``fn`` whose result for the same arguments (by their ``repr``) is computed by one worker
    of the run and read back (pickled) by the others."""

    @functools.wraps(fn)
    def shared(*args: Any, **kwargs: Any) -> R:
        if _root is None:
            return fn(*args, **kwargs)
        key = repr((fn.__module__, fn.__qualname__, args, sorted(kwargs.items())))
        name = f"{fn.__name__}-{hashlib.sha256(key.encode()).hexdigest()[:20]}.pickle"
        path = made_once(_root, name, lambda out: out.write_bytes(pickle.dumps(fn(*args, **kwargs))))
        result: R = pickle.loads(path.read_bytes())
        return result

    return shared
