"""``rig serve`` as a child process for the benchmarks: the real command, on loopback.

:class:`ServiceProcess` starts ``python -m cli serve ...`` on a free port with the
environment it is given (cache directories), records its output, waits for ``/readyz``, reads
the child's RSS and CPU time from ``/proc`` and stops it with SIGINT (the service's normal
shutdown), killing it only if it does not stop.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import httpx

__all__ = [
    "RigRun",
    "ServiceProcess",
    "free_port",
    "proc_cpu_s",
    "proc_rss_mb",
    "quick_serve_args",
    "run_rig",
    "serve_args_for",
]

REPO = Path(__file__).resolve().parents[1]


def free_port() -> int:
    """A TCP port free on loopback right now (the child binds it a moment later)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def proc_rss_mb(pid: int) -> float:
    """Resident set size of ``pid`` (VmRSS) in MiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError(f"no VmRSS for pid {pid}")


def proc_cpu_s(pid: int) -> float:
    """User + system CPU time of ``pid`` (all its threads) in seconds."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    ticks = os.sysconf("SC_CLK_TCK")
    return (int(fields[11]) + int(fields[12])) / ticks  # utime, stime (fields 14, 15)


class ServiceProcess:
    """``rig serve ARGS --port P`` in a child process (see module doc)."""

    def __init__(self, args: Sequence[str], env: Mapping[str, str] | None = None) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        cmd = [sys.executable, "-m", "cli", "serve", *args, "--port", str(self.port)]
        child_env = {**os.environ, **(env or {})}
        child_env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), child_env.get("PYTHONPATH")]))
        self.started = time.monotonic()
        self.proc = subprocess.Popen(
            cmd,
            cwd=REPO,
            env=child_env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            errors="replace",
        )
        self.output: list[str] = []
        self._reader = threading.Thread(target=self._read, name="bench-service-output", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.output.append(line.rstrip("\n"))

    @property
    def pid(self) -> int:
        return self.proc.pid

    def wait_ready(self, timeout_s: float) -> float:
        """Seconds from the launch to the first 200 of ``/readyz`` (a depth frame exists)."""
        deadline = self.started + timeout_s
        with httpx.Client(timeout=1.0) as client:
            while time.monotonic() < deadline:
                if self.proc.poll() is not None:
                    tail = "\n".join(self.output[-15:])
                    raise RuntimeError(f"rig serve exited with {self.proc.returncode}:\n{tail}")
                try:
                    if client.get(self.url + "/readyz").status_code == 200:
                        return time.monotonic() - self.started
                except httpx.HTTPError:
                    pass
                time.sleep(0.02)
        raise RuntimeError(f"rig serve not ready after {timeout_s:g} s:\n" + "\n".join(self.output[-15:]))

    def rss_mb(self) -> float:
        return proc_rss_mb(self.pid)

    def cpu_s(self) -> float:
        return proc_cpu_s(self.pid)

    def stop(self, timeout_s: float = 15.0) -> int:
        """SIGINT (graceful shutdown), then SIGKILL if it hangs; the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5.0)
        self._reader.join(2.0)
        return self.proc.returncode

    def __enter__(self) -> ServiceProcess:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()


def quick_serve_args() -> list[str]:
    """``rig serve`` arguments for quick runs: the small MJPEG recording (320×240 lenses) and a
    160×120 VPC with 32 disparities."""
    from bench.common import bench_cache_dir
    from bench.recordings import MjpegSpec, ensure_mjpeg_recording

    recording = ensure_mjpeg_recording(MjpegSpec(frames=4, views=1, scale=0.25))
    path = bench_cache_dir() / "quick-serve.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("vpc: {width: 160, height: 120}\nstereo: {disparity_range: 32}\n")
    return ["--recording", str(recording), "--config", str(path)]


def serve_args_for(quick: bool, recording: Path | None) -> list[str]:
    """``rig serve`` arguments of a benchmark: the quick recording, ``recording`` or the demo."""
    if quick:
        return quick_serve_args()
    if recording is not None:
        return ["--recording", str(recording)]
    return ["--demo"]


@dataclass(frozen=True)
class RigRun:
    """A finished ``rig`` command: exit status (negative: the signal that ended it), the child's
    own peak RSS (``ru_maxrss`` from ``wait4``), wall time and its output lines."""

    exit_status: int
    peak_rss_mb: float
    seconds: float
    lines: list[str]


def run_rig(args: Sequence[str], env: Mapping[str, str] | None = None, timeout_s: float = 600.0) -> RigRun:
    """``python -m cli ARGS`` to its end (killed after ``timeout_s``), measured."""
    child_env = {**os.environ, **(env or {})}
    child_env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), child_env.get("PYTHONPATH")]))
    t0 = time.monotonic()
    cmd = [sys.executable, "-m", "cli", *args]
    proc = subprocess.Popen(cmd, cwd=REPO, env=child_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    killer = threading.Timer(timeout_s, proc.kill)
    killer.start()
    assert proc.stdout is not None
    output = proc.stdout.read()  # to the end of the child's output
    _, status, usage = os.wait4(proc.pid, 0)  # the child's own peak RSS
    killer.cancel()
    proc.returncode = os.waitstatus_to_exitcode(status)
    lines = [ln for ln in output.decode(errors="replace").splitlines() if ln.strip()]
    return RigRun(proc.returncode, usage.ru_maxrss / 1024, time.monotonic() - t0, lines)
