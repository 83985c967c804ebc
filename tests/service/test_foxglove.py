"""The live Foxglove server of ``rig serve``: a client speaking foxglove.websocket.v1 subscribes
and decodes depth, the point cloud, camera images and calibrations, transforms and health with
the schemas the server advertised; a viewer that stops reading does not stop the depth worker."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import pytest

from rig.ros.names import RosNames
from service.store import PublishedResult
from tests.helpers.service import InProcessServer, StartApp
from tests.helpers.waiting import wait_for
from tests.service.foxglove_client import FoxgloveClient

N = RosNames()
FOXGLOVE = {"enabled": True, "port": 0, "max_fps": 10.0, "cloud_stride": 2}


def record_published(live: InProcessServer) -> dict[int, PublishedResult]:
    """Every result the worker publishes from now on, by capture time (the last 200)."""
    store = live.runtime.store
    published: dict[int, PublishedResult] = {}
    original = store.publish
    lock = threading.Lock()

    def publish(result: PublishedResult) -> None:
        with lock:
            published[result.ts_ns] = result
            while len(published) > 200:
                published.pop(next(iter(published)))
        original(result)

    store.publish = publish  # type: ignore[method-assign]
    return published


def decode_image(msg: Any) -> np.ndarray[Any, Any]:
    assert msg.encoding == "32FC1" and msg.step == 4 * msg.width
    return np.frombuffer(msg.data, "<f4").reshape(msg.height, msg.width)


def stamp_ns(msg: Any) -> int:
    return int(msg.timestamp.seconds) * 1_000_000_000 + int(msg.timestamp.nanos)


def test_client_receives_decodable_depth_and_the_rest(start_app: StartApp) -> None:
    live = start_app(foxglove=FOXGLOVE)
    published = record_published(live)
    fox = live.app.state.foxglove
    client = FoxgloveClient(fox.port)
    try:
        topics = [N.depth_image, N.points, N.raw_image("left", compressed=False), N.raw_info("left"),
                  N.depth_info, N.range_image, N.tf_static, N.health]  # fmt: skip
        client.subscribe(topics)
        assert client.server_info is not None and client.server_info["name"] == "odfc-rig"
        assert client.channels[N.depth_image].schema_name == "foxglove.RawImage"
        assert client.channels[N.points].schema_name == "foxglove.PointCloud"
        assert client.channels[N.raw_info("left")].schema_name == "foxglove.CameraCalibration"
        assert client.channels[N.tf_static].schema_name == "foxglove.FrameTransforms"
        got: dict[str, list[tuple[int, Any]]] = {}
        deadline = time.monotonic() + 30
        while not all(len(got.get(t, [])) >= 2 for t in topics if t not in (N.tf_static, N.health)) or not (
            got.get(N.tf_static) and got.get(N.health)
        ):
            assert time.monotonic() < deadline, {t: len(v) for t, v in got.items()}
            topic, log_time, msg = client.next_message()
            got.setdefault(topic, []).append((log_time, msg))
    finally:
        client.close()
    vpc = live.runtime.pipeline.pair.camera

    def recorded(topic: str) -> list[tuple[int, Any]]:
        # The first messages can carry frames published before the hook was installed: only
        # frames older than every recorded one may be missing from the record.
        kept = [(t, m) for t, m in got[topic] if t in published]
        older = [t for t, _ in got[topic] if t not in published]
        assert kept and all(t < min(k for k, _ in kept) for t in older), (topic, older, list(published))
        return kept

    for log_time, msg in recorded(N.depth_image):
        depth = decode_image(msg)
        assert depth.shape == (vpc.height, vpc.width) and msg.frame_id == N.rect_frame("left")
        assert stamp_ns(msg) == log_time
        # Exactly the depth the worker published for that frame.
        assert np.array_equal(depth, published[log_time].frame.depth, equal_nan=True)
        assert np.isfinite(depth).mean() > 0.5
    for log_time, msg in recorded(N.points):
        fields = {f.name: (f.offset, f.type) for f in msg.fields}
        assert fields["x"] == (0, 7) and fields["red"] == (14, 1) and msg.point_stride == 16  # FLOAT32, UINT8
        assert msg.frame_id == N.rig_frame
        pts = np.frombuffer(msg.data, "<f4").reshape(-1, 4)[:, :3]
        ref, _ = live.runtime.pipeline.point_cloud(published[log_time].frame, 2)
        assert np.array_equal(pts, ref)
    _, cal = got[N.raw_info("left")][0]
    assert cal.distortion_model == "kannala_brandt" and len(cal.D) == 4 and len(cal.P) == 12
    _, rect = got[N.depth_info][0]
    assert rect.distortion_model == "plumb_bob" and list(rect.K) == vpc.K.reshape(-1).tolist()
    _, image = got[N.raw_image("left", compressed=False)][0]  # the rendered recording is PNG: raw pixels
    assert (image.width, image.height) == (
        live.runtime.rig.cameras["left"].width,
        live.runtime.rig.cameras["left"].height,
    )
    _, tf = got[N.tf_static][0]
    edges = {(t.parent_frame_id, t.child_frame_id) for t in tf.transforms}
    left_cam = N.camera_frame("left")
    assert edges >= {(N.body_frame, N.rig_frame), (N.rig_frame, left_cam), (left_cam, N.rect_frame("left"))}
    _, health = got[N.health][0]
    assert health["status"] in ("ok", "degraded") and "left" in health["cameras"]


@pytest.mark.slow
def test_a_viewer_that_stops_reading_does_not_stop_the_worker(
    start_app: StartApp,
) -> None:
    live = start_app(foxglove={**FOXGLOVE, "message_backlog": 8})
    fox = live.app.state.foxglove
    stalled = FoxgloveClient(fox.port)
    reader = FoxgloveClient(fox.port)
    topics = [N.depth_image, N.points, N.range_image, N.raw_image("left", compressed=False)]
    try:
        stalled.subscribe(topics)  # and then never reads again
        reader.subscribe([N.depth_image])
        worker = live.runtime.worker
        before, published_before = worker.stats().last_index, fox.stats().published
        stamps = []
        deadline = time.monotonic() + 4.0
        while time.monotonic() < deadline:
            _, t, _ = reader.next_message()
            stamps.append(t)
        # The worker and the publisher went on, and the reading viewer kept getting new frames.
        assert worker.stats().last_index - before >= 10
        assert fox.stats().published - published_before >= 10
        assert len(set(stamps)) >= 10 and stamps == sorted(stamps)
        wait_for(lambda: live.runtime.health().status == "ok", 5, "health ok")
    finally:
        stalled.close()
        reader.close()
