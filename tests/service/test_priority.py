"""Depth threads run ahead of HTTP (rig.priority, ``server.depth_nice``): the capture, worker and
pool threads take the configured nice value, the thread serving HTTP keeps its own."""

from __future__ import annotations

import errno
import logging
import os
import resource
import threading
from collections.abc import Iterator

import pytest

import rig.postprocess as finish_module
from rig import priority
from tests.helpers.service import StartServer

NICE = -3


def _may_lower_nice(nice: int) -> bool:
    """Root, or a nice limit (RLIMIT_NICE = 20 - lowest nice) that allows ``nice``."""
    if os.geteuid() == 0:
        return True
    soft, _ = resource.getrlimit(resource.RLIMIT_NICE)
    return soft == resource.RLIM_INFINITY or 20 - soft <= nice


@pytest.fixture(autouse=True)
def _restore() -> Iterator[None]:
    before = priority.configured_nice()
    yield
    priority.configure(before)


def _nices(prefix: str) -> dict[str, int]:
    return {
        t.name: priority.thread_nice(t.native_id) for t in threading.enumerate() if t.name.startswith(prefix)
    }


def test_depth_threads_take_the_nice_value_http_keeps_its_own(
    start_server: StartServer, caplog: pytest.LogCaptureFixture
) -> None:
    own = priority.thread_nice()
    caplog.set_level(logging.INFO, logger="rig.priority")
    live = start_server(depth_nice=NICE)
    depth = _nices("rig-depth-") | _nices("rig-left-") | _nices("rig-right-")
    assert {"rig-depth-prepare", "rig-depth-match", "rig-depth-worker", "rig-left-capture"} <= set(depth)
    # The finish stage's pool (shared by the process) is made anew for a new nice value.
    pool = finish_module.refine_pool()
    if finish_module._REFINE_THREADS >= 2:  # else there is no pool (one core)
        assert pool is not None and pool._threads, "no frame went through the banded finish"
        depth |= {t.name: priority.thread_nice(t.native_id) for t in pool._threads if t.native_id is not None}
    assert live.thread.native_id is not None
    # The uvicorn thread ran the lifespan that started the depth threads: it is HTTP, untouched.
    assert priority.thread_nice(live.thread.native_id) == own
    if _may_lower_nice(NICE):
        assert set(depth.values()) == {NICE}, depth
        assert not [r for r in caplog.records if "normal priority" in r.getMessage()]
    else:
        assert set(depth.values()) == {own}, depth
        said = [r for r in caplog.records if "normal priority" in r.getMessage()]
        assert len(said) == 1 and "LimitNICE" in said[0].getMessage()


def test_no_permission_is_said_once_and_threads_carry_on(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    def refuse(which: int, who: int, value: int) -> None:
        raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(os, "setpriority", refuse)
    caplog.set_level(logging.INFO, logger="rig.priority")
    priority.configure(priority.thread_nice() - 1)
    results: list[bool] = []
    threads = [
        threading.Thread(target=lambda: results.append(priority.apply_to_current_thread())) for _ in range(3)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert results == [False, False, False]
    said = [r.getMessage() for r in caplog.records if r.name == "rig.priority"]
    assert len(said) == 1 and "needs root, CAP_SYS_NICE or LimitNICE" in said[0], said


def test_null_leaves_threads_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[int, int, int]] = []
    monkeypatch.setattr(os, "setpriority", lambda *a: calls.append(a))
    priority.configure(None)
    assert priority.apply_to_current_thread() is False
    assert priority.prioritise_native_threads() == 0
    assert calls == []
