"""Inputs that every test worker of a run reads the same: made once per run, not once per worker.

Under pytest-xdist each worker has its own base temporary directory, under one directory of the
run (:func:`run_root`); :func:`made_once` makes a file or directory there under a lock (the first
worker to ask makes it, the others wait for it and read it). Without xdist the run's directory
is the session's own."""

from __future__ import annotations

import fcntl
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

__all__ = ["made_once", "run_root"]


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
