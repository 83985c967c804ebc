"""``rig serve`` under a real, low descriptor limit (``RLIMIT_NOFILE`` lowered in the child):
a limit that cannot hold ``server.max_connections`` is refused at start with one line naming
the setting, and a flood of connections that never finish their request, several times the
limit, leaves the cameras their descriptors: ``/health`` answers, no frame is lost to EMFILE
or counted corrupt, and the service is whole once the flood has gone
(docs/reliability.md, "Hostile clients")."""

from __future__ import annotations

import contextlib
import os
import socket
from pathlib import Path

import httpx
import pytest

from service.serve import FD_RESERVE
from tests.helpers.command import assert_one_line_error, clean_env, run_rig, start_serve, wait_healthy
from tests.helpers.service import LOAD_REASONS, write_serve_config

pytestmark = [pytest.mark.timeout(300)]

NOFILE = 256
MAX_CONNECTIONS = 64  # + FD_RESERVE = 192 descriptors: within NOFILE
FLOOD = 600  # connections, more than twice NOFILE


def test_a_descriptor_limit_below_max_connections_is_refused_at_start(
    tmp_path: Path, jpeg_recording: Path
) -> None:
    # The default 128 connections need 128 + FD_RESERVE descriptors; the hard limit is 150.
    result = run_rig(
        ["serve", "--recording", str(jpeg_recording), "--port", "0"], clean_env(tmp_path), nofile=150
    )
    line = assert_one_line_error(result, "field 'server.max_connections'", "ulimit -n")
    assert f"need {128 + FD_RESERVE} file descriptors" in line and "may open 150" in line, line


def _slowloris(port: int) -> socket.socket | None:
    """A connection with a request head that never ends (None if the connect itself failed)."""
    try:
        sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        sock.sendall(b"GET /health HTTP/1.1\r\nHost: x\r\nX-a: b\r\n")
    except OSError:
        return None
    return sock


def _open_descriptors(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def test_a_connection_flood_beyond_the_descriptor_limit_leaves_the_cameras_working(
    tmp_path: Path, jpeg_recording: Path, lut_cache: Path
) -> None:
    cfg = write_serve_config(
        tmp_path / "serve.yaml",
        jpeg_recording,
        tmp_path,
        lut_cache,
        port=0,
        max_connections=MAX_CONNECTIONS,
        request_timeout_s=120.0,  # the connection cap, not the timeout, must hold the flood
    )
    served = start_serve(["--config", str(cfg), "--log-level", "warning"], clean_env(tmp_path), nofile=NOFILE)
    socks: list[socket.socket] = []
    try:
        wait_healthy(served.url, 60)
        before = httpx.get(served.url + "health", timeout=10).json()["cameras"]
        peak = 0
        for k in range(FLOOD):
            if (sock := _slowloris(served.port)) is not None:
                socks.append(sock)
            if k % 50 == 0:
                peak = max(peak, _open_descriptors(served.proc.pid))
        during = [httpx.get(served.url + "health", timeout=10) for _ in range(10)]
        peak = max(peak, _open_descriptors(served.proc.pid))
        for sock in socks:
            with contextlib.suppress(OSError):
                sock.close()
        socks.clear()
        after = wait_healthy(served.url, 30)
    finally:
        for sock in socks:
            sock.close()
        text = served.stop()
    print(f"\n{FLOOD} slowloris connections under ulimit -n {NOFILE}: server peak {peak} descriptors")
    assert [r.status_code for r in during] == [200] * 10, [r.text[:200] for r in during]
    # Never down, and degraded only for what the flood's CPU costs (frames dropped), not for a
    # camera that could not open its frames.
    docs = [r.json() for r in during]
    assert all(d["status"] in ("ok", "degraded") for d in docs), docs
    assert all(LOAD_REASONS.fullmatch(reason) for d in docs for reason in d["reasons"]), docs
    assert peak <= MAX_CONNECTIONS + FD_RESERVE, peak
    for name, camera in after["cameras"].items():
        assert camera["state"] == "available", camera
        assert camera["frames_corrupt"] == before[name]["frames_corrupt"] == 0, camera
    assert "EMFILE" not in text and "out of system resource" not in text, text[-3000:]
    assert "Traceback" not in text, text[-3000:]
