"""The ``rig`` console command in subprocesses: one-shot runs, the one-line error contract, and
``rig serve`` waited for until it prints its URL and answers."""

from __future__ import annotations

import os
import re
import resource
import selectors
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx

from tests.helpers.waiting import wait_for

__all__ = [
    "RIG",
    "Served",
    "assert_one_line_error",
    "clean_env",
    "limit_descriptors",
    "run_rig",
    "start_serve",
    "wait_answering",
    "wait_healthy",
]

#: The console script installed next to this interpreter (``pip install -e .``).
RIG = Path(sys.executable).with_name("rig")
URL_RE = re.compile(r"depth service: (http://(\S+?):(\d+)/)")


def clean_env(tmp: Path | None = None, **extra: str | Path) -> dict[str, str]:
    """This process's environment without any ``RIG_*`` variable (the tests' own must not reach
    the command), unbuffered, 250 columns so rich wraps no message; with ``tmp``, the user cache
    and data directories (LUT cache, demo recording) under it. ``extra`` is added last."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("RIG_")}
    env.update(PYTHONUNBUFFERED="1", COLUMNS="250")
    if tmp is not None:
        env.update(XDG_CACHE_HOME=str(tmp / "cache"), XDG_DATA_HOME=str(tmp / "data"))
    env.update({k: str(v) for k, v in extra.items()})
    return env


def limit_descriptors(nofile: int) -> Callable[[], None]:
    """A ``preexec_fn`` that lowers the child's ``RLIMIT_NOFILE``, soft and hard, to ``nofile``."""

    def lower() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))

    return lower


def run_rig(
    args: Sequence[str | Path],
    env: dict[str, str] | None = None,
    timeout: float = 300,
    cwd: Path | None = None,
    nofile: int | None = None,
) -> subprocess.CompletedProcess[str]:
    """``rig ARGS`` to completion, output captured (``env`` defaults to :func:`clean_env`); with
    ``nofile``, under that descriptor limit."""
    assert RIG.is_file(), f"console script not installed at {RIG}"
    return subprocess.run(
        [str(RIG), *map(str, args)],
        env=clean_env() if env is None else env,
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=cwd,
        preexec_fn=None if nofile is None else limit_descriptors(nofile),
    )


def assert_one_line_error(result: subprocess.CompletedProcess[str], *needles: str) -> str:
    """Exit status 2, exactly one non-empty line on stderr starting with ``error:``, no traceback;
    returns that line."""
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    context = f"args={result.args!r}\nstdout={result.stdout!r}\nstderr={result.stderr!r}"
    assert result.returncode == 2, context
    assert len(lines) == 1 and lines[0].startswith("error:"), context
    assert "Traceback" not in result.stderr + result.stdout, context
    for needle in needles:
        assert needle in lines[0], (needle, context)
    return lines[0]


@dataclass
class Served:
    """A ``rig serve`` subprocess and what it printed up to its URL line."""

    proc: subprocess.Popen[str]
    url: str  # http://host:port/
    host: str
    port: int
    output: list[str]

    def stop(self) -> str:
        """SIGTERM (graceful) and the rest of its output; kills it if it does not stop in 60 s."""
        if self.proc.poll() is None:
            self.proc.terminate()
        try:
            out, _ = self.proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, _ = self.proc.communicate()
        return "".join(self.output) + (out or "")


def start_serve(
    args: list[str], env: dict[str, str], timeout: float = 120, nofile: int | None = None
) -> Served:
    """``rig serve ARGS`` until it prints its URL (stdout and stderr merged); with ``nofile``,
    under that descriptor limit. The URL line comes when the socket is bound: use
    :func:`wait_answering` before relying on the app."""
    proc = subprocess.Popen(
        [str(RIG), "serve", *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        preexec_fn=None if nofile is None else limit_descriptors(nofile),
    )
    assert proc.stdout is not None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    output: list[str] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not sel.select(timeout=1.0):
            if proc.poll() is not None:
                break
            continue
        line = proc.stdout.readline()
        if not line:
            break
        output.append(line)
        m = URL_RE.search(line)
        if m:
            return Served(proc, m.group(1), m.group(2), int(m.group(3)), output)
    proc.kill()
    proc.communicate()
    raise AssertionError("rig serve printed no URL:\n" + "".join(output))


def wait_answering(
    url: str,
    path: str = "livez",
    timeout_s: float = 60.0,
    accept: Callable[[httpx.Response], bool] = lambda r: r.status_code == 200,
) -> httpx.Response:
    """The first response of ``GET url + path`` that ``accept`` takes, polled every 0.1 s
    (connection errors count as no answer)."""

    def answer() -> httpx.Response | None:
        try:
            r = httpx.get(url + path, timeout=5)
        except httpx.TransportError:
            return None
        return r if accept(r) else None

    return wait_for(answer, timeout_s, f"{url}{path} to answer", poll_s=0.1)


def wait_healthy(url: str, timeout_s: float = 60.0) -> dict[str, Any]:
    """The first ``/health`` document of the service at ``url`` whose status is ok."""

    def ok(r: httpx.Response) -> bool:
        return r.status_code == 200 and r.json()["status"] == "ok"

    health: dict[str, Any] = wait_answering(url, "health", timeout_s, ok).json()
    return health
