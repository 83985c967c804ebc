"""The service on a rig of N cameras (the app in process): four file cameras replaying the small
rendered ring, every pair's depth per synchronised set, /range?pair=, the panorama (PNG and npy)
fused on request, the fused /pointcloud, health per camera and per pair, recordings of N cameras,
and the errors: an unknown pair (404 with the list), a panorama of a two-camera rig (404)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from io import BytesIO
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from rig.recording import Recording
from rig.ros.names import RosNames
from tests.helpers.rings import ring_service_settings, write_small_ring
from tests.helpers.service import TOKEN, InProcessServer
from tests.helpers.waiting import wait_for
from tests.service.foxglove_client import FoxgloveClient

PAIRS = ["cam1-cam2", "cam2-cam3", "cam3-cam4", "cam4-cam1"]


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory, lut_cache: Path) -> Iterator[InProcessServer]:
    tmp = tmp_path_factory.mktemp("ring-service")
    rec = write_small_ring(tmp / "ring", frames=2)
    foxglove = {"enabled": True, "port": 0, "max_fps": 5.0, "cloud_stride": 4}
    settings = ring_service_settings(rec, tmp, lut_cache, foxglove=foxglove)
    server = InProcessServer(settings).start()
    server.wait_ready(120.0)
    yield server
    server.stop()


def test_every_pair_and_the_panorama_of_the_latest_set(served: InProcessServer) -> None:
    c = served.client
    runtime = served.runtime
    assert runtime.ring is not None and runtime.ring.labels == PAIRS
    first = c.get("/range", params={"format": "npy"})
    default = c.get("/range", params={"format": "npy", "pair": "cam1-cam2"})
    assert first.status_code == default.status_code == 200
    for label in PAIRS[1:]:
        r = c.get("/range", params={"format": "npy", "pair": label})
        assert r.status_code == 200, r.text
        rng = np.load(BytesIO(r.content))
        assert rng.dtype == np.float32 and np.isfinite(rng).mean() > 0.2, label
    unknown = c.get("/range", params={"pair": "cam1-cam3"})
    assert unknown.status_code == 404
    assert unknown.json()["detail"] == f"no pair 'cam1-cam3'; the rig's pairs: {', '.join(PAIRS)}"
    info = c.get("/panorama/info").json()
    assert info["pairs"] == PAIRS and info["projection"] == "equirect"
    # The configured resolution (panorama.px_per_deg), not the default's 1440x720.
    assert (info["width"], info["height"]) == (720, 360) and info["px_per_deg"] == pytest.approx(2.0)
    png = c.get("/panorama")
    assert png.status_code == 200 and png.headers["X-Range-Scale"] == "0.001"
    mm = cv2.imdecode(np.frombuffer(png.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert mm.dtype == np.uint16 and mm.shape == (info["height"], info["width"])
    npy = c.get("/panorama", params={"format": "npy"})
    seq = int(png.headers["X-Frame-Seq"])
    if int(npy.headers["X-Frame-Seq"]) == seq:  # the same set: the same panorama, two encodings
        rng = np.load(BytesIO(npy.content))
        assert np.array_equal(mm == 0, ~(np.isfinite(rng) & (np.rint(rng * 1000) <= 65535)))
    print(f"\nsmall ring in the service: the panorama ranges {100 * np.count_nonzero(mm) / mm.size:.1f} %")
    assert np.count_nonzero(mm) > 0.3 * mm.size
    jpeg = c.get("/panorama/colorized")  # the dashboard's: colour, the panorama's size
    assert jpeg.status_code == 200 and jpeg.headers["content-type"] == "image/jpeg"
    colour = cv2.imdecode(np.frombuffer(jpeg.content, np.uint8), cv2.IMREAD_COLOR)
    assert colour.shape == (info["height"], info["width"], 3)
    cloud = c.get("/pointcloud", params={"stride": 2})
    assert cloud.status_code == 200 and b"element vertex" in cloud.content[:300]
    one = c.get("/pointcloud", params={"stride": 2, "pair": "cam2-cam3"})
    assert one.status_code == 200 and one.content != cloud.content


def test_health_per_camera_and_per_pair(served: InProcessServer) -> None:
    health = served.client.get("/health").json()
    assert sorted(health["cameras"]) == ["cam1", "cam2", "cam3", "cam4"]
    assert list(health["pairs"]) == PAIRS
    for label, pair in health["pairs"].items():
        assert pair["cameras"] == label.split("-") and pair["baseline_m"] > 0
        assert pair["seq"] is not None and 0.0 < pair["valid_fraction"] <= 1.0, label


def test_a_recording_of_the_rig_holds_every_camera(served: InProcessServer) -> None:
    c = served.client
    auth = {"Authorization": f"Bearer {TOKEN}"}
    assert c.post("/recordings", json={"name": "ringrec"}, headers=auth).status_code in (200, 201)
    root = served.settings.server.recordings_dir / "ringrec"
    wait_for(lambda: (root / "frames.csv").is_file() and len(Recording(root).pairs) >= 2, 60.0, "two sets")
    assert c.post("/recordings/ringrec/stop", headers=auth).status_code == 200
    rec = Recording(root)
    assert rec.cameras == ["cam1", "cam2", "cam3", "cam4"] and rec.calibration_path is not None
    for row in rec.pairs:
        assert max(row.stamps) - min(row.stamps) <= served.runtime.capture.skew_gate_ns


def test_foxglove_publishes_each_pair_the_panorama_and_every_camera(served: InProcessServer) -> None:
    n = RosNames()
    pair = n.for_pair("cam2-cam3")
    topics = [
        n.panorama_image,
        n.points,
        pair.depth_image,
        n.raw_image("cam3", compressed=False),
        n.tf_static,
    ]
    client = FoxgloveClient(served.app.state.foxglove.port)
    try:
        client.subscribe(topics)
        assert client.channels[n.points].schema_name == "foxglove.PointCloud"
        assert client.channels[pair.depth_image].schema_name == "foxglove.RawImage"
        got: dict[str, Any] = {}
        deadline = time.monotonic() + 60
        while set(got) != set(topics):
            assert time.monotonic() < deadline, sorted(got)
            # The test's deadline, not the client's 10 s: a loaded machine may fuse slowly.
            topic, _, msg = client.next_message(max(0.1, deadline - time.monotonic()))
            got.setdefault(topic, msg)
    finally:
        client.close()
    info = served.client.get("/panorama/info").json()
    assert (got[n.panorama_image].width, got[n.panorama_image].height) == (info["width"], info["height"])
    frames = {t.child_frame_id for t in got[n.tf_static].transforms}
    assert {n.camera_frame(c) for c in ("cam1", "cam2", "cam3", "cam4")} | {n.panorama_frame} <= frames
