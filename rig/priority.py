"""CPU priority of the depth threads: capture, worker and recording ahead of HTTP clients.

The depth worker keeps every core busy, so CPU spent serving clients (and, on the robot, by the
clients themselves) comes straight out of the frame rate. Linux has per-thread nice values: the
service sets its own threads (``rig-*``: camera supervisors, the worker's stages and pools, the
recording writer, plus OpenCV's native worker threads) to :func:`configure`'s value, and leaves
the HTTP threads at the process's. Lowering nice below 0 needs root, ``CAP_SYS_NICE`` or a nice
limit (systemd ``LimitNICE=-5``, as in ``deploy/rig.service``); without it the threads stay at
normal priority and the service says so once in its log. Threads inherit their creator's nice
value, so work a depth thread starts runs at its priority too.
"""

from __future__ import annotations

import logging
import os
import threading
from pathlib import Path

__all__ = [
    "apply_to_current_thread",
    "configure",
    "configured_nice",
    "prioritise_native_threads",
    "thread_nice",
]

log = logging.getLogger(__name__)

_lock = threading.Lock()
_nice: int | None = None
_warned = False
_TASKS = Path("/proc/self/task")


def configure(nice: int | None) -> None:
    """The nice value depth threads take from now on (None: leave them alone)."""
    global _nice, _warned
    with _lock:
        _nice = nice
        _warned = False


def configured_nice() -> int | None:
    return _nice


def thread_nice(tid: int | None = None) -> int:
    """The nice value of thread ``tid`` of this process (default: the calling thread)."""
    return os.getpriority(os.PRIO_PROCESS, tid if tid is not None else threading.get_native_id())


def _set(tid: int, nice: int) -> bool:
    global _warned
    try:
        os.setpriority(os.PRIO_PROCESS, tid, nice)
        return True
    except PermissionError as err:
        with _lock:
            first, _warned = not _warned, True
        if first:
            log.info(
                "depth threads stay at normal priority: nice %d needs root, CAP_SYS_NICE or "
                "LimitNICE=%d (%s)",
                nice,
                nice,
                err.strerror,
            )
        return False
    except OSError:  # the thread ended meanwhile (ESRCH), or no such call here
        return False


def apply_to_current_thread() -> bool:
    """Give the calling thread the configured nice value; True if it has it now. Call first
    thing in a depth thread (also a ``ThreadPoolExecutor`` ``initializer``)."""
    nice = _nice
    if nice is None or not hasattr(os, "setpriority"):
        return False
    tid = threading.get_native_id()
    if thread_nice(tid) == nice:
        return True
    return _set(tid, nice)


def prioritise_native_threads() -> int:
    """Give the configured nice value to this process's threads that Python did not start
    (OpenCV's thread pool, which may have been started by the main thread); the number set."""
    nice = _nice
    if nice is None or not _TASKS.is_dir():
        return 0
    python_tids = {t.native_id for t in threading.enumerate()}
    done = 0
    for entry in _TASKS.iterdir():
        tid = int(entry.name)
        if tid in python_tids:
            continue
        try:
            if thread_nice(tid) == nice or _set(tid, nice):
                done += 1
        except OSError:  # ended between listing and asking
            continue
    return done
