"""One owner of the rectified pair and the stereo parameters in effect, seen from the API: what
``/config`` and ``/calibration`` report is what the pipeline runs with (a lat-lon pair's real
size, not a pinhole's defaults), a change is the pipeline's one path and re-estimates the memory
budget (refused when it cannot fit), readers never wait for a change, and a middleware added to
the app after it is built applies to every route, the fast path's answers included. In process
(tests.helpers.service.in_process: the socket is not the subject)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from prometheus_client.parser import text_string_to_metric_families
from starlette.types import ASGIApp, Message, Receive, Scope, Send

import service.memory
from rig.memory_budget import MIB
from rig.rectified import RectifiedPairConfig
from service.errors import SettingsError
from tests.helpers.service import AUTH, InProcessServer, SmallRecording, in_process, service_settings
from tests.helpers.waiting import wait_for

pytestmark = pytest.mark.timeout(180)


class StampEveryResponse:
    """A middleware an embedding application adds after ``create_app``."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        async def stamped(message: Message) -> None:
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message["headers"], (b"x-stamp", b"1")]}
            await send(message)

        await self.app(scope, receive, stamped)


@pytest.fixture
def latlon(small_recording: SmallRecording, tmp_path: Path, lut_cache: Path) -> Iterator[InProcessServer]:
    settings = service_settings(small_recording.loop, tmp_path, lut_cache).model_copy(
        update={"rectified": RectifiedPairConfig(px_per_deg=3.0)}
    )
    with in_process(settings) as server:
        wait_for(lambda: server.client.get("/depth").status_code == 200, 60, "a depth frame")
        yield server


def test_config_and_calibration_report_the_lat_lon_pair_in_effect(latlon: InProcessServer) -> None:
    latlon_client, runtime = latlon.client, latlon.app.state.runtime
    cam = runtime.pipeline.in_effect.camera
    config = latlon_client.get("/config")
    doc = config.json()
    assert config.headers["ETag"] == f'"{doc["revision"]}"'
    rect = doc["rectified"]
    assert rect["projection"] == "latlon" and (rect["width"], rect["height"]) == (cam.width, cam.height)
    assert (rect["width"], rect["height"]) != (640, 480) and abs(rect["px_per_deg"] - 3.0) < 1e-9
    # As configured: no pinhole size for a lat-lon pair.
    assert doc["vpc"]["projection"] == "latlon" and doc["vpc"]["width"] is None
    calibration = latlon_client.get("/calibration").json()["vpc"]
    assert {k: calibration[k] for k in ("width", "height", "fx", "cx")} == {
        k: rect[k] for k in ("width", "height", "fx", "cx")
    }
    depth = latlon_client.get("/depth", params={"format": "npy"})
    assert depth.status_code == 200


def _budget(client: httpx.Client) -> float:
    text = client.get("/metrics").text
    for family in text_string_to_metric_families(text):
        if family.name == "rig_memory_budget_bytes":
            return float(family.samples[0].value)
    raise AssertionError("no rig_memory_budget_bytes in /metrics")


def test_a_change_is_in_effect_everywhere_and_re_estimates_the_budget(
    latlon: InProcessServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    latlon_client, runtime = latlon.client, latlon.app.state.runtime
    before = latlon_client.get("/config")
    budget = _budget(latlon_client)
    r = latlon_client.patch("/config", json={"stereo": {"disparity_range": 96}}, headers=AUTH)
    assert r.status_code == 200, r.text
    after = r.json()
    assert (
        after["revision"] == before.json()["revision"] + 1 and r.headers["ETag"] == f'"{after["revision"]}"'
    )
    assert after["stereo"]["disparity_range"] == 96
    assert latlon_client.get("/config").json()["stereo"]["disparity_range"] == 96
    assert runtime.pipeline.in_effect.stereo.disparity_range == 96
    # The budget follows the parameters in effect (the matcher's buffers grow with the range).
    assert _budget(latlon_client) > budget
    # A change whose budget cannot fit what the machine has left is refused, and nothing changes.
    monkeypatch.setattr(service.memory, "available_memory", lambda: 0)
    huge = latlon_client.patch(
        "/config", json={"stereo": {"full_dp": True, "sgbm_mode": "hh", "disparity_range": 192}}, headers=AUTH
    )
    assert huge.status_code == 422, huge.text
    assert "MiB" in huge.json()["detail"] and "left" in huge.json()["detail"]
    now = latlon_client.get("/config").json()
    assert now["revision"] == after["revision"] and now["stereo"]["disparity_range"] == 96


def test_a_stale_revision_changes_nothing(latlon: InProcessServer) -> None:
    latlon_client = latlon.client
    revision = latlon_client.get("/config").json()["revision"]
    stale = latlon_client.patch(
        "/config",
        json={"stereo": {"disparity_range": 48}},
        headers={**AUTH, "If-Match": f'"{revision - 1}"'},
    )
    assert stale.status_code == 412 and f'"{revision}"' in stale.json()["detail"]
    assert latlon_client.get("/config").json()["revision"] == revision


def test_a_middleware_added_later_applies_to_every_route(
    small_recording: SmallRecording, tmp_path: Path, lut_cache: Path
) -> None:
    settings = service_settings(small_recording.loop, tmp_path, lut_cache, health_max_age_s=1.0)
    with in_process(settings, lambda app: app.add_middleware(StampEveryResponse)) as server:
        client, app = server.client, server.app
        paths = app.openapi()["paths"]
        routes = [path for path, ops in paths.items() if "get" in ops and "{" not in path]
        wait_for(lambda: client.get("/depth").status_code == 200, 60, "a depth frame")
        client.get("/depth")  # cached now: the next plain poll is the fast path's
        client.get("/health")
        answered: list[str] = []
        assert app.fast_path_on is True
        for path in ("/depth", "/health", *routes, "/frames/left", "/camera_info/left"):
            # The endless stream's headers are checked on a HEAD.
            r = client.head(path) if path == "/stream.mjpg" else client.get(path)
            assert r.headers.get("x-stamp") == "1", f"{path} ({r.status_code}) skipped the middleware"
            answered.append(path)
    assert {"/depth", "/health", "/config", "/calibration", "/metrics", "/"} <= set(answered)


def test_the_fast_path_answers_pass_through_the_middleware(
    small_recording: SmallRecording, tmp_path: Path, lut_cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The stamp above is on the fast path's own answers, not only on the routes' (which answer
    when the fast path misses)."""
    import service.app

    fast: list[str] = []
    real = service.app.answer_hot_request

    async def spy(state: object, scope: Scope, send: Send) -> bool:
        done = await real(state, scope, send)
        if done:
            fast.append(scope["path"])
        return done

    monkeypatch.setattr(service.app, "answer_hot_request", spy)
    settings = service_settings(small_recording.loop, tmp_path, lut_cache, health_max_age_s=1.0)
    with in_process(settings, lambda app: app.add_middleware(StampEveryResponse)) as server:
        client = server.client
        wait_for(lambda: client.get("/depth").status_code == 200, 60, "a depth frame")
        client.get("/health")
        stamped = [client.get(p).headers.get("x-stamp") for p in ("/depth", "/depth", "/health")]
    assert {"/depth", "/health"} <= set(fast) and stamped == ["1", "1", "1"]


def test_a_budget_that_does_not_fit_is_refused_at_start_in_pair_terms(
    small_recording: SmallRecording, tmp_path: Path, lut_cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(service.memory, "available_memory", lambda: 16 * MIB)
    settings = service_settings(small_recording.loop, tmp_path, lut_cache)
    with (
        pytest.raises(SettingsError, match=r"pinhole pair with 64 disparities needs about") as refused,
        in_process(settings),
    ):
        pass
    assert "rectified.width/rectified.height" in str(refused.value)
