"""Errors that say what happened, over HTTP: non-finite numbers and booleans where numbers belong
are 422 naming the field (never a 500), several wrong fields are listed at once, HEAD answers
wherever GET does, and a recordings directory that cannot hold recordings is named as such."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from tests.helpers.service import TOKEN, InProcessServer, StartApp

AUTH = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}

# Python's JSON reader takes NaN, Infinity and -Infinity, and reads 1e400 as infinity.
NON_FINITE = ("NaN", "Infinity", "-Infinity", "1e400")


def _send(live: InProcessServer, method: str, path: str, body: str) -> httpx.Response:
    return live.client.request(method, path, content=body, headers=AUTH, timeout=30)


def _fields(r: httpx.Response) -> list[str]:
    return [".".join(str(p) for p in e["loc"]) for e in r.json()["detail"]]


@pytest.mark.parametrize("number", NON_FINITE)
def test_non_finite_numbers_are_422_naming_the_field(shared_app: InProcessServer, number: str) -> None:
    cases = [
        ("PATCH", "/config", f'{{"stereo": {{"uniqueness_ratio": {number}}}}}', "stereo.uniqueness_ratio"),
        ("PATCH", "/config", f'{{"stereo": {{"speckle_size": {number}}}}}', "stereo.speckle_size"),
        (
            "POST",
            "/cameras/left/faults",
            f'{{"fault": {{"kind": "stall", "duration_s": {number}}}}}',
            "duration_s",
        ),
        (
            "POST",
            "/cameras/left/faults",
            f'{{"fault": {{"kind": "stall", "duration_s": 1, "at_s": {number}}}}}',
            "at_s",
        ),
        ("POST", "/recordings", f'{{"name": {number}}}', "body.name"),
    ]
    for method, path, body, field in cases:
        r = _send(shared_app, method, path, body)
        assert r.status_code == 422, (body, r.status_code, r.text)
        assert any(f.endswith(field) for f in _fields(r)), (body, r.text)


def test_a_boolean_is_no_number(shared_app: InProcessServer) -> None:
    for path, body, field in (
        ("/config", '{"stereo": {"speckle_size": true}}', "stereo.speckle_size"),
        ("/cameras/left/faults", '{"fault": {"kind": "corrupt", "count": true}}', "count"),
        ("/cameras/left/faults", '{"fault": {"kind": "stall", "duration_s": false}}', "duration_s"),
    ):
        r = _send(shared_app, "PATCH" if path == "/config" else "POST", path, body)
        assert r.status_code == 422 and any(f.endswith(field) for f in _fields(r)), (body, r.text)


def test_several_wrong_fields_are_listed_at_once(shared_app: InProcessServer) -> None:
    r = _send(shared_app, "PATCH", "/config", '{"stereo": {"speckle_size": -5, "median": 4, "P1": "x"}}')
    assert r.status_code == 422
    assert {"body.stereo.speckle_size", "body.stereo.median", "body.stereo.P1"} <= set(_fields(r))
    # Rules between fields: every broken one in the one message.
    body = '{"stereo": {"correlation_window_size": 4, "P1": 100, "P2": 50}}'
    detail = str(_send(shared_app, "PATCH", "/config", body).json()["detail"])
    assert "correlation_window_size must be odd" in detail and "P2 (50.0) must be larger than P1" in detail


def test_head_answers_wherever_get_does(shared_app: InProcessServer) -> None:
    spec = shared_app.client.get("/openapi.json").json()
    paths = [p.replace("{camera}", "left") for p, ops in spec["paths"].items() if "get" in ops]
    assert len(paths) >= 15
    for path in [*paths, "/no-such-page"]:
        query = {"max_frames": 1} if path == "/stream.mjpg" else {}
        got = shared_app.client.get(path, params=query, timeout=30)
        head = shared_app.client.head(path, timeout=30)
        assert head.status_code == got.status_code, (path, head.status_code, got.status_code)
        assert head.headers.get("content-type") == got.headers.get("content-type"), path
        assert head.content == b"", path
    # POST-only paths name every method they take, HEAD included where GET is.
    r = shared_app.client.head("/recordings/x/stop")
    assert r.status_code == 405 and r.headers["allow"] == "POST"
    assert set(shared_app.client.delete("/recordings").headers["allow"].split(", ")) == {
        "GET",
        "HEAD",
        "POST",
    }


def test_a_recordings_dir_that_is_a_file_is_named(start_app: StartApp, tmp_path: Path) -> None:
    a_file = tmp_path / "not-a-dir"
    a_file.write_text("x")
    live = start_app(recordings_dir=str(a_file))
    r = _send(live, "POST", "/recordings", '{"name": "run1"}')
    assert r.status_code == 500 and "internal error" not in r.text
    assert r.json()["detail"] == f"server.recordings_dir {a_file}: cannot hold recordings (not a directory)"
    assert live.client.get("/recordings").json() == []
    assert live.client.get("/health").json()["recording"] is None
