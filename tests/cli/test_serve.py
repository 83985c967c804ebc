"""``rig serve`` as a real subprocess: refusals are one line + exit 2, a recording is served over
HTTP, SIGINT/SIGTERM shut down gracefully, and ``--demo`` works from an empty cache."""

from __future__ import annotations

import signal
import socket
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from rig.rectified import DEFAULT_PROJECTION
from tests.helpers.command import (
    RIG,
    Served,
    assert_one_line_error,
    clean_env,
    run_rig,
    start_serve,
    wait_answering,
    wait_healthy,
)
from tests.helpers.service import SmallRecording


def serve_env(tmp: Path, **extra: str) -> dict[str, str]:
    """Caches, data and recordings under ``tmp``."""
    return clean_env(tmp, RIG_SERVER__RECORDINGS_DIR=str(tmp / "recordings"), **extra)


def test_non_loopback_without_token_refused(tmp_path: Path) -> None:
    result = run_rig(["serve", "--host", "0.0.0.0"], serve_env(tmp_path))
    assert_one_line_error(result, "0.0.0.0", "RIG_API_TOKEN")


def test_bad_config_names_file_and_field(tmp_path: Path) -> None:
    cfg = tmp_path / "rig.yaml"
    cfg.write_text("server: {port: 99999}\n")
    assert_one_line_error(
        run_rig(["serve", "--config", str(cfg)], serve_env(tmp_path)), str(cfg), "server.port"
    )


def test_missing_recording_and_calibration(tmp_path: Path, small_recording: SmallRecording) -> None:
    env = serve_env(tmp_path)
    assert_one_line_error(
        run_rig(["serve", "--recording", str(tmp_path / "nope")], env), "--recording", "nope"
    )
    bare = tmp_path / "bare"
    bare.mkdir()
    for f in ("recording.json", "frames.csv"):
        (bare / f).write_bytes((small_recording.loop / f).read_bytes())
    assert_one_line_error(run_rig(["serve", "--recording", str(bare)], env), "--calibration")
    both = run_rig(["serve", "--demo", "--recording", str(bare)], env)
    assert_one_line_error(both, "--demo")


def test_busy_port_is_one_line_with_the_way_out(tmp_path: Path) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        args = ["serve", "--port", str(port), "--config", str(_empty_config(tmp_path))]
        result = run_rig(args, serve_env(tmp_path))
        assert_one_line_error(result, f"127.0.0.1:{port}", "Address already in use", "--port P", "--port 0")
        # Refused before the pipeline, the app and uvicorn are imported (seconds on a busy board):
        # only the settings are read by then.
        traced = run_rig(args, serve_env(tmp_path, PYTHONPROFILEIMPORTTIME="1"))
    assert traced.returncode == 2
    imported = {line.rsplit("|", 1)[-1].strip() for line in traced.stderr.splitlines() if "|" in line}
    assert "service.settings" in imported
    assert not imported & {"uvicorn", "fastapi", "service.app", "service.runtime", "rig.pipeline"}, imported


def _empty_config(tmp: Path) -> Path:
    # Cameras that cannot open are fine here: the bind fails before any camera is touched.
    cfg = tmp / "cams.yaml"
    cfg.write_text(
        "cameras:\n  left: {kind: v4l2, device: /dev/null-left}\n"
        "  right: {kind: v4l2, device: /dev/null-right}\ncalibration: {path: missing.yaml}\n"
    )
    return cfg


@pytest.fixture
def served_recording(tmp_path: Path, small_recording: SmallRecording) -> Iterator[Served]:
    env = serve_env(tmp_path, RIG_VPC__WIDTH="320", RIG_VPC__HEIGHT="240", RIG_STEREO__DISPARITY_RANGE="64")
    served = start_serve(
        ["--port", "0", "--recording", str(small_recording.loop), "--log-level", "warning"], env, timeout=90
    )
    assert served.host == "127.0.0.1"  # loopback unless configured
    yield served
    if served.proc.poll() is None:
        served.proc.kill()
        served.proc.wait()


@pytest.mark.timeout(240)
@pytest.mark.parametrize("stop_signal", [signal.SIGINT, signal.SIGTERM])
def test_serve_recording_then_graceful_stop(served_recording: Served, stop_signal: signal.Signals) -> None:
    health = wait_healthy(served_recording.url, 90)
    assert health["cameras"]["left"]["kind"] == "file"  # type: ignore[index]
    r = httpx.get(served_recording.url + "depth", timeout=10)
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    assert r.headers["X-Depth-Scale"] == "0.001" and int(r.headers["X-Frame-Seq"]) >= 0
    cfg = httpx.get(served_recording.url + "config", timeout=10).json()
    assert cfg["vpc"]["width"] == 320  # RIG_VPC__WIDTH reached the pipeline
    # A stream client is connected while we stop: shutdown must still be prompt and clean.
    with httpx.stream("GET", served_recording.url + "stream.mjpg", timeout=30) as stream:
        next(stream.iter_bytes())
        served_recording.proc.send_signal(stop_signal)
        out, _ = served_recording.proc.communicate(timeout=60)
    text = "".join(served_recording.output) + out
    assert served_recording.proc.returncode == 0, text
    assert "depth service stopped (worker and capture threads joined)" in text
    assert "Traceback" not in text


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_serve_demo_from_an_empty_cache(tmp_path: Path) -> None:
    env = serve_env(tmp_path, PATH="/usr/bin:/bin")  # the rig command is not on PATH: said how
    served = start_serve(["--port", "0", "--demo", "--log-level", "warning"], env, timeout=800)
    assert served.host == "127.0.0.1"  # loopback unless configured
    try:
        # The demo made an API token and printed the dashboard's URL with it, as notebook servers do.
        line = served.output[-1]
        token = line.split("?token=", 1)[1].split()[0]
        assert line.startswith(f"depth service: {served.url}?token={token}") and len(token) >= 32
        wait_answering(served.url)
        patch = {"stereo": {"median": 3}}
        assert httpx.patch(served.url + "config", json=patch, timeout=30).status_code == 401
        r = httpx.patch(
            served.url + "config", json=patch, headers={"Authorization": f"Bearer {token}"}, timeout=60
        )
        assert r.status_code == 200 and r.json()["stereo"]["median"] == 3
        assert (tmp_path / "cache" / "odfc-rig" / "demo").is_dir()  # rendered into the user cache dir
        health = wait_healthy(served.url, 120)
        assert health["status"] == "ok"
        r = httpx.get(served.url + "depth", timeout=30)
        assert r.status_code == 200 and r.headers["content-type"] == "image/png"
        # The demo shows the default rectified pair, and its range.
        vpc = httpx.get(served.url + "calibration", timeout=30).json()["vpc"]
        assert vpc["projection"] == DEFAULT_PROJECTION
        r = httpx.get(served.url + "range", timeout=30)
        assert r.status_code == 200 and r.headers["X-Range-Scale"] == "0.001"
        page = httpx.get(served.url, timeout=10)
        assert page.status_code == 200 and 'id="depth-img"' in page.text
    finally:
        served.proc.send_signal(signal.SIGINT)
        served.proc.wait(timeout=60)
        assert served.proc.stdout is not None
        rest = served.proc.stdout.read()  # the reader's buffer too (communicate reads past it)
    assert served.proc.returncode == 0
    assert f"API docs: {served.url}docs (Authorize with the token {token})" in rest
    bindir = RIG.resolve().parent  # said relative to the working directory when inside it
    shown = bindir.relative_to(Path.cwd()) if bindir.is_relative_to(Path.cwd()) else bindir
    assert f"the rig command is {shown / 'rig'}; `. {shown / 'activate'}` puts it on PATH" in rest


def test_a_configured_token_is_never_printed(tmp_path: Path, small_recording: SmallRecording) -> None:
    secret = "configured-secret-0123456789abcdef"
    env = serve_env(tmp_path, RIG_API_TOKEN=secret, RIG_VPC__WIDTH="320", RIG_VPC__HEIGHT="240")
    served = start_serve(
        ["--port", "0", "--recording", str(small_recording.loop), "--log-level", "warning"], env
    )
    try:
        wait_answering(served.url)
        assert httpx.get(served.url + "config", timeout=30).json()["server"]["api_token_set"]
    finally:
        text = served.stop()
    assert secret not in text and "?token=" not in text
    assert f"depth service: {served.url}  (dashboard; API docs at {served.url}docs" in text


def test_served_connections_have_tcp_nodelay() -> None:
    """``rig serve`` binds its own socket; asyncio sets TCP_NODELAY on accepted connections only
    for IPPROTO_TCP sockets, and without it every keep-alive response waits for a delayed ACK."""
    import asyncio

    from service.listen import bind_socket

    async def accepted_nodelay() -> int:
        sock = bind_socket("127.0.0.1", 0)
        got: asyncio.Future[int] = asyncio.get_running_loop().create_future()

        def on_client(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            got.set_result(writer.get_extra_info("socket").getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY))
            writer.close()

        server = await asyncio.start_server(on_client, sock=sock)
        async with server:
            _, writer = await asyncio.open_connection(*sock.getsockname()[:2])
            value = await asyncio.wait_for(got, 10)
            writer.close()
        return value

    assert asyncio.run(accepted_nodelay()) != 0
