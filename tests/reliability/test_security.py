"""Security of the service as deployed: loopback by default, no non-loopback bind without a
token, every state-changing endpoint closed without the right token, and recording names that
cannot reach outside ``recordings_dir``."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from service.settings import ServerSettings, Settings, is_loopback
from tests.helpers.command import assert_one_line_error, clean_env, run_rig, start_serve, wait_answering
from tests.helpers.service import AUTH, TOKEN, InProcessServer, StartApp, StartServer, write_serve_config
from tests.helpers.waiting import wait_for

pytestmark = [pytest.mark.timeout(300)]


# ----- bind address ------------------------------------------------------------------------------
def listening_addresses(port: int) -> set[str]:
    """Local addresses with a TCP socket listening on ``port`` (from /proc/net/tcp and tcp6)."""
    found = set()
    for table, family in (("/proc/net/tcp", socket.AF_INET), ("/proc/net/tcp6", socket.AF_INET6)):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except FileNotFoundError:
            continue
        for line in lines:
            fields = line.split()
            local, state = fields[1], fields[3]
            addr_hex, port_hex = local.split(":")
            if state != "0A" or int(port_hex, 16) != port:  # 0A = LISTEN
                continue
            raw = bytes.fromhex(addr_hex)
            # The kernel prints each 32-bit word in host (little-endian) order.
            raw = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
            found.add(socket.inet_ntop(family, raw))
    return found


def test_default_bind_is_loopback_in_settings() -> None:
    assert ServerSettings().host == "127.0.0.1" and is_loopback(ServerSettings().host)
    assert Settings().server.host == "127.0.0.1"


@pytest.mark.slow
def test_rig_serve_listens_on_loopback_only_by_default(jpeg_recording: Path, tmp_path: Path) -> None:
    env = clean_env(tmp_path, RIG_VPC__WIDTH="320", RIG_VPC__HEIGHT="240", RIG_STEREO__DISPARITY_RANGE="64")
    served = start_serve(["--recording", str(jpeg_recording), "--port", "0", "--log-level", "warning"], env)
    try:
        assert served.host == "127.0.0.1" and served.url == f"http://127.0.0.1:{served.port}/"
        wait_answering(served.url)
        assert listening_addresses(served.port) == {"127.0.0.1"}
    finally:
        text = served.stop()
    assert served.proc.returncode == 0 and "Traceback" not in text


@pytest.mark.slow
@pytest.mark.parametrize(
    "how",
    [
        ["--host", "0.0.0.0"],
        ["--host", "::"],
        ["--host", "192.0.2.10"],  # a specific non-loopback address (TEST-NET-1)
        "env",
        "config",
    ],
    ids=["cli-any-v4", "cli-any-v6", "cli-address", "env", "config-file"],
)
def test_non_loopback_without_token_refuses_to_start(tmp_path: Path, how: list[str] | str) -> None:
    env = clean_env(tmp_path)
    if how == "env":
        env["RIG_SERVER__HOST"] = "0.0.0.0"
        args = ["serve"]
    elif how == "config":
        cfg = tmp_path / "serve.yaml"
        cfg.write_text("server: {host: 0.0.0.0, port: 0}\n")
        args = ["serve", "--config", str(cfg)]
    else:
        assert isinstance(how, list)
        args = ["serve", *how, "--port", "0"]
    result = run_rig(args, env, timeout=60)
    line = assert_one_line_error(result, "refusing to bind non-loopback address", "RIG_API_TOKEN")
    assert "api_token" not in result.stdout and TOKEN not in line


@pytest.mark.slow
def test_a_token_too_short_is_refused_too(tmp_path: Path) -> None:
    result = run_rig(
        ["serve", "--host", "0.0.0.0", "--port", "0"], clean_env(tmp_path, RIG_API_TOKEN="short")
    )
    assert_one_line_error(result, "RIG_API_TOKEN", "at least 16 characters")


@pytest.mark.slow
def test_non_loopback_with_a_token_starts(jpeg_recording: Path, lut_cache: Path, tmp_path: Path) -> None:
    cfg = write_serve_config(
        tmp_path / "serve.yaml", jpeg_recording, tmp_path, lut_cache, host="0.0.0.0", port=0
    )
    served = start_serve(["--config", str(cfg), "--log-level", "warning"], clean_env(tmp_path))
    try:
        base = f"http://127.0.0.1:{served.port}"
        wait_answering(base + "/")
        assert served.host == "0.0.0.0" and listening_addresses(served.port) == {"0.0.0.0"}
        assert httpx.patch(base + "/config", json={"stereo": {"median": 3}}, timeout=10).status_code == 401
    finally:
        served.stop()


# ----- the bearer token --------------------------------------------------------------------------
#: A valid request for each state-changing operation, so a 401 is never a masked 422.
VALID_CALLS: dict[tuple[str, str], tuple[str, Any]] = {
    ("PATCH", "/config"): ("/config", {"stereo": {"median": 3}}),
    ("POST", "/recordings"): ("/recordings", {"name": "intruder"}),
    ("POST", "/recordings/{name}/stop"): ("/recordings/intruder/stop", None),
    ("POST", "/cameras/{camera}/faults"): (
        "/cameras/left/faults",
        {"fault": {"kind": "stall", "duration_s": 30}},
    ),
}
BAD_HEADERS = {
    "none": {},
    "wrong token": {"Authorization": "Bearer wrong-token-0123456789abcdef"},
    "token prefix": {"Authorization": f"Bearer {TOKEN[:-1]}"},
    "token + suffix": {"Authorization": f"Bearer {TOKEN}x"},
    "no scheme": {"Authorization": TOKEN},
    "basic scheme": {"Authorization": f"Basic {TOKEN}"},
    "empty bearer": {"Authorization": "Bearer"},
    "query instead": {},  # the token as a query parameter is not a credential
}


def state_changing_operations(client: httpx.Client) -> set[tuple[str, str]]:
    spec = client.get("/openapi.json", timeout=10).json()
    return {
        (m.upper(), path)
        for path, ops in spec["paths"].items()
        for m in ops
        if m.upper() in ("POST", "PUT", "PATCH", "DELETE")
    }


def snapshot(live: InProcessServer) -> dict[str, Any]:
    """What an accepted request would have changed: stereo parameters and recordings (a stall
    injected into the left camera is :func:`left_camera_delivers`' to see)."""
    return {
        "stereo": live.client.get("/config", timeout=10).json()["stereo"],
        "recordings": live.client.get("/recordings", timeout=10).json(),
    }


def left_seq(live: InProcessServer) -> int:
    seq: int = live.client.get("/health", timeout=10).json()["cameras"]["left"]["last_seq"]
    return seq


def left_camera_delivers(live: InProcessServer) -> bool:
    """The left camera keeps delivering frames (an injected 30 s stall would stop them). Its
    state or loss counter would not do: a camera thread starved on a loaded machine loses a
    frame or turns unavailable for a moment without any fault."""
    start = left_seq(live)
    return bool(wait_for(lambda: left_seq(live) >= start + 3, 5, "three more left frames"))


@pytest.mark.parametrize("token_configured", [True, False], ids=["with-token", "no-token-configured"])
def test_every_state_changing_endpoint_needs_the_token(start_app: StartApp, token_configured: bool) -> None:
    live = start_app(**({} if token_configured else {"api_token": None}))
    operations = state_changing_operations(live.client)
    assert operations == set(VALID_CALLS), "a new state-changing endpoint needs a row in VALID_CALLS"
    before = snapshot(live)
    for (method, _), (path, body) in VALID_CALLS.items():
        for label, headers in BAD_HEADERS.items():
            params = {"token": TOKEN, "access_token": TOKEN} if label == "query instead" else None
            r = live.client.request(method, path, json=body, headers=headers, params=params, timeout=10)
            assert r.status_code == 401, (method, path, label, r.status_code, r.text)
            assert r.headers["www-authenticate"] == "Bearer" and r.json()["detail"]
        # Even the right token is refused when the server has none configured.
        r = live.client.request(method, path, json=body, headers=AUTH, timeout=10)
        assert (r.status_code == 401) == (not token_configured), (method, path, r.status_code)
        if not token_configured:
            assert "no API token configured" in r.json()["detail"]
        # An invalid body does not reveal validation before authentication either.
        r = live.client.request(method, path, content=b"{", headers={"content-type": "application/json"})
        assert r.status_code == 401, (method, path, "invalid body", r.status_code)
    if not token_configured:
        assert snapshot(live) == before  # nothing changed at all
        assert left_camera_delivers(live)


# ----- recording names ---------------------------------------------------------------------------
BAD_NAMES = {
    "parent": "../x",
    "dotdot": "..",
    "dot": ".",
    "absolute": "/tmp/rig-h10-escape",
    "nested": "a/b",
    "deep escape": "x/../../rig-h10-escape",
    "backslashes": "..\\rig-h10-escape",
    "percent-encoded": "%2e%2e",
    "percent slash": "..%2Fx",
    "unicode": "récording",
    "unicode slash": "..\u2215x",
    "fullwidth dots": "\uff0e\uff0e",
    "empty": "",
    "300 chars": "a" * 300,
    "65 chars": "a" * 65,
    "NUL": "a\x00b",
    "newline": "a\nb",
    "hidden": ".hidden",
    "leading dash": "-rf",
    "space": "a b",
    "dots inside": "a..b",
}


def tree(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


@pytest.mark.parametrize("name", list(BAD_NAMES.values()), ids=list(BAD_NAMES))
def test_recording_names_that_could_escape_are_rejected(
    start_app: StartApp, tmp_path: Path, name: str
) -> None:
    live = start_app(ready=False)
    recordings = live.settings.server.recordings_dir
    before = tree(tmp_path)
    r = live.client.post("/recordings", json={"name": name}, headers=AUTH, timeout=10)
    assert r.status_code == 422 and r.json()["detail"], (name, r.status_code, r.text)
    # The same name as a path segment of the stop endpoint (percent-encoded by the client).
    quoted = httpx.URL(live.base_url + "/recordings/").copy_with(
        raw_path=b"/recordings/" + _quote(name) + b"/stop"
    )
    r = live.client.post(quoted, headers=AUTH, timeout=10)
    assert 400 <= r.status_code < 500 and r.status_code != 401, (name, r.status_code)
    assert tree(tmp_path) == before  # nothing created anywhere under the test's directory
    assert not recordings.exists() or not any(recordings.iterdir())
    for escape in (Path("/tmp/rig-h10-escape"), tmp_path.parent / "rig-h10-escape"):
        assert not escape.exists()


def _quote(name: str) -> bytes:
    from urllib.parse import quote

    return quote(name, safe="").encode("ascii") or b"%20"


def test_a_plain_name_is_created_directly_inside_recordings_dir(start_app: StartApp) -> None:
    live = start_app()
    recordings = live.settings.server.recordings_dir
    r = live.client.post("/recordings", json={"name": "Run_1.a-b"}, headers=AUTH, timeout=10)
    assert r.status_code == 201, r.text
    assert Path(r.json()["path"]) == (recordings / "Run_1.a-b").resolve()
    wait_for(lambda: live.client.get("/recordings").json()[0]["pairs"] >= 1, 20, "a recorded pair")
    r = live.client.post("/recordings/Run_1.a-b/stop", headers=AUTH, timeout=30)
    assert r.status_code == 200 and [p.name for p in recordings.iterdir()] == ["Run_1.a-b"]


# ----- request bodies ----------------------------------------------------------------------------
def concrete(path: str) -> str:
    return path.replace("{name}", "x").replace("{camera}", "left")


def test_oversize_bodies_are_refused_on_every_endpoint_before_anything_reads_them(
    start_server: StartServer,
) -> None:
    live = start_server(ready=False, max_body_bytes=4096)
    spec = httpx.get(live.base_url + "/openapi.json", timeout=10).json()
    operations = [
        (m.upper(), concrete(p), "requestBody" in op)
        for p, ops in spec["paths"].items()
        for m, op in ops.items()
    ]
    assert sum(takes_body for *_, takes_body in operations) == 3  # PATCH /config, 2 POSTs with JSON
    big = b'{"name": "' + b"x" * 8192 + b'"}'

    def chunked() -> Iterator[bytes]:  # no Content-Length: counted while it streams in
        for _ in range(8):
            yield b"y" * 1024

    headers = {"content-type": "application/json"}
    for method, path, takes_body in operations:
        cases: list[tuple[str, Any, dict[str, str]]] = [
            ("declared", big, AUTH),
            ("declared, no token", big, {}),
        ]
        if takes_body:
            # A streamed body is judged as it is read; endpoints without a body never read it
            # (uvicorn's flow control keeps it off the heap), so only a declared length matters there.
            cases.append(("chunked", chunked(), AUTH))
        for label, content, extra in cases:
            r = httpx.request(
                method, live.base_url + path, content=content, headers={**headers, **extra}, timeout=10
            )
            assert r.status_code == 413, (method, path, label, r.status_code)
            assert "4096" in r.json()["detail"]
    # A lying Content-Length is refused as well, and the service is unharmed by all of it.
    with socket.create_connection(("127.0.0.1", live.port), timeout=10) as sock:
        sock.sendall(
            b"POST /recordings HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            + f"Authorization: Bearer {TOKEN}\r\n".encode()
            + b"Content-Length: 12abc\r\n\r\n{}"
        )
        status_line = sock.recv(4096).split(b"\r\n", 1)[0]
    assert status_line.startswith(b"HTTP/1.1 400"), status_line
    assert httpx.get(live.base_url + "/livez", timeout=10).status_code == 200
    assert not live.settings.server.recordings_dir.exists() or not any(
        live.settings.server.recordings_dir.iterdir()
    )
