"""The hot requests answered ahead of FastAPI's routing (service.fast_path, the ASGI app's
innermost middleware: run here in process): the same response as the route for the same frame or
health document, every other request left to the app, and the app's middleware applied to its
answers."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import cv2
import httpx
import numpy as np
import pytest

import service.app
from tests.helpers.service import SMALL_SPEC, InProcessServer, StartApp
from tests.helpers.waiting import wait_for

pytestmark = pytest.mark.timeout(120)


@pytest.fixture
def fast_answers(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[str]]:
    """Paths (with query) the fast path answered during the test."""
    answered: list[str] = []
    real = service.app.answer_hot_request

    async def spy(state: Any, scope: Any, send: Any) -> bool:
        done = await real(state, scope, send)
        if done:
            answered.append(
                scope["path"] + ("?" + scope["query_string"].decode() if scope["query_string"] else "")
            )
        return done

    monkeypatch.setattr(service.app, "answer_hot_request", spy)
    yield answered


@pytest.fixture
def frozen(shared_app: InProcessServer) -> InProcessServer:
    """This module's app with its worker stopped (its latest frame stays the latest) and the fast
    path on."""
    if shared_app.runtime.worker.is_alive():
        shared_app.runtime.worker.stop()
    shared_app.app.fast_path_on = True
    return shared_app


def _comparable(r: httpx.Response) -> tuple[int, dict[str, str], bytes]:
    headers = {k.lower(): v for k, v in r.headers.items() if k.lower() != "date"}
    return r.status_code, headers, r.content


@pytest.mark.parametrize(
    "path",
    ["/depth", "/depth?format=png", "/depth?format=npy", "/disparity", "/disparity?format=npy"],
)
def test_a_polled_frame_gets_the_routes_response(
    frozen: InProcessServer, fast_answers: list[str], path: str
) -> None:
    live = frozen
    client = live.client
    live.app.fast_path_on = False
    by_route = client.get(path)  # encodes the body into the frame's cache
    assert by_route.status_code == 200 and fast_answers == []
    live.app.fast_path_on = True
    fast = client.get(path)
    assert fast_answers == [path]
    assert _comparable(fast) == _comparable(by_route)
    seq = int(fast.headers["X-Frame-Seq"])
    assert seq == live.runtime.store.latest.seq  # type: ignore[union-attr]


def test_the_fast_bodies_decode_to_the_frame(frozen: InProcessServer, fast_answers: list[str]) -> None:
    live = frozen
    frame = live.runtime.store.latest.frame  # type: ignore[union-attr]
    client = live.client
    for _ in range(2):  # the first may encode (route), the second is cached (fast path)
        png = client.get("/depth")
        npy = client.get("/disparity", params={"format": "npy"})
    assert fast_answers[-2:] == ["/depth", "/disparity?format=npy"]
    depth_mm = cv2.imdecode(np.frombuffer(png.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert depth_mm.shape == (SMALL_SPEC.vpc.height, SMALL_SPEC.vpc.width)
    ok = frame.valid & (depth_mm > 0)
    assert ok.sum() > 0.3 * ok.size
    np.testing.assert_allclose(depth_mm[ok] * 1e-3, frame.depth[ok], atol=6e-4)
    disparity = np.load(__import__("io").BytesIO(npy.content))
    np.testing.assert_array_equal(disparity, frame.disparity)


def test_a_fresh_health_document_is_answered_as_the_route_does(
    start_app: StartApp, fast_answers: list[str]
) -> None:
    live = start_app(health_max_age_s=1.0)  # one document for the three requests
    client = live.client
    live.app.fast_path_on = False
    by_route = client.get("/health")  # builds the shared document
    live.app.fast_path_on = True
    fast = client.get("/health")
    with_query = client.get("/health", params={"verbose": "1"})
    assert fast_answers == ["/health"]
    assert _comparable(fast) == _comparable(by_route)
    assert fast.headers["content-type"] == "application/json" and fast.json()["status"] == "ok"
    assert _comparable(with_query) == _comparable(by_route)  # by the route, from the same document


def test_a_stale_health_document_is_left_to_the_route(start_app: StartApp, fast_answers: list[str]) -> None:
    live = start_app(health_max_age_s=0.0)  # never fresh: every request builds one
    client = live.client
    first, second = client.get("/health"), client.get("/health")
    assert first.status_code == second.status_code == 200
    assert first.json()["uptime_s"] < second.json()["uptime_s"]
    assert fast_answers == []


@pytest.mark.parametrize(
    ("method", "path", "headers", "status"),
    [
        ("GET", "/depth?format=bmp", {}, 422),  # validation is the route's
        ("GET", "/depth?format=png&stride=2", {}, 200),  # unknown parameters: the route ignores them
        ("GET", "/depth/", {}, 307),  # the router redirects a trailing slash
        ("POST", "/depth", {}, 405),
        ("GET", "/depth", {"Content-Length": "4"}, 200),  # a body goes through the size limit
        ("GET", "/depth/colorized", {}, 200),
    ],
)
def test_other_requests_go_to_the_app(
    frozen: InProcessServer,
    fast_answers: list[str],
    method: str,
    path: str,
    headers: dict[str, str],
    status: int,
) -> None:
    client = frozen.client
    client.get("/depth")
    client.get("/depth")  # cached now: a plain poll would be answered fast
    before = list(fast_answers)
    content = b"abcd" if "Content-Length" in headers else None
    r = client.request(method, path, headers=headers, content=content)
    assert r.status_code == status
    assert fast_answers == before
    if status >= 400:
        assert "detail" in r.json()


def test_the_fast_path_answers_through_cors(start_app: StartApp, fast_answers: list[str]) -> None:
    """The fast path is the app's innermost middleware: CORS wraps its answers too."""
    origin = "http://robot-ui.test"
    live = start_app(cors_origins=[origin])
    assert live.app.fast_path_on is True
    client = live.client
    wait_for(lambda: client.get("/depth").status_code == 200, 10.0, "a depth frame")
    client.get("/depth")  # cached now
    r = client.get("/depth", headers={"Origin": origin})
    assert r.status_code == 200 and r.headers["access-control-allow-origin"] == origin
    assert "/depth" in fast_answers
