"""Colour cameras: depth from luma, colour VPC images and point cloud colours made on request.

The app (in process) replays colour 4:2:2 MJPEG frames (what UVC cameras send). The worker decodes and
remaps only the luma; ``/frames/{camera}?view=vpc`` and ``/pointcloud`` still give colour, made
from the raw frame of the same result with OpenCV's own decode and the pipeline's LUT.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest

from bench.recordings import ensure_mjpeg_recording
from tests.helpers.service import QUICK_MJPEG, InProcessServer, same_frame, service_settings


@pytest.fixture(scope="module")
def colour_server(
    tmp_path_factory: pytest.TempPathFactory, lut_cache: Path, bench_cache: Path
) -> Iterator[InProcessServer]:
    tmp = tmp_path_factory.mktemp("colour")
    # 4 pairs of the prototype rig at quarter size (320×240 fisheyes), colour JPEG 4:2:2: the quick
    # benchmarks' recording, rendered once per session.
    recording = ensure_mjpeg_recording(QUICK_MJPEG, cache_dir=bench_cache)
    live = InProcessServer(service_settings(recording, tmp, lut_cache)).start()
    live.wait_ready()
    yield live
    live.stop()


def decode(data: bytes, flags: int) -> np.ndarray:
    return np.asarray(cv2.imdecode(np.frombuffer(data, np.uint8), flags))


class Fetched:
    def __init__(self, r: httpx.Response) -> None:
        assert r.status_code == 200, r.text
        self.seq = int(r.headers["X-Frame-Seq"])
        self.content = r.content


def test_depth_is_computed_from_luma_and_colour_is_made_once_on_request(
    colour_server: InProcessServer,
) -> None:
    runtime = colour_server.runtime
    pipeline = runtime.pipeline
    result = runtime.store.latest
    assert result is not None
    for cam, name, vpc in zip(
        ("left", "right"), pipeline.names, (result.frame.left_rect, result.frame.right_rect), strict=True
    ):
        raw = result.raw_frame(cam).raw
        assert raw is not None
        # The matched image is the LUT remap of the JPEG's own luma, bit for bit.
        assert vpc.ndim == 2
        luma = decode(raw, cv2.IMREAD_GRAYSCALE)
        np.testing.assert_array_equal(vpc, pipeline.rectify_camera(name, luma)[0])
        colour = result.rect_image(cam)
        assert colour.shape == (*vpc.shape, 3) and not colour.flags.writeable
        assert result.rect_image(cam) is colour  # made once per result
        np.testing.assert_array_equal(colour, pipeline.rectify_camera(name, decode(raw, cv2.IMREAD_COLOR))[0])
        # A colour scene: the channels differ (a gray camera would give equal ones).
        assert np.abs(colour[..., 0].astype(int) - colour[..., 2].astype(int)).mean() > 3.0


def test_vpc_endpoint_serves_colour_of_the_same_frame(colour_server: InProcessServer) -> None:
    runtime = colour_server.runtime
    client = colour_server.client
    for cam, name in zip(("left", "right"), runtime.pipeline.names, strict=True):
        vpc, raw = same_frame(
            lambda c=cam: Fetched(client.get(f"/frames/{c}", params={"view": "vpc"})),
            lambda c=cam: Fetched(client.get(f"/frames/{c}", params={"view": "raw"})),
        )
        served = decode(vpc.content, cv2.IMREAD_UNCHANGED)
        expected = runtime.pipeline.rectify_camera(name, decode(raw.content, cv2.IMREAD_COLOR))[0]
        assert served.shape == expected.shape and served.ndim == 3
        # Only the JPEG encoding of the response (quality 85, noisy texture) between them.
        assert np.abs(served.astype(int) - expected.astype(int)).mean() < 6.0


def test_point_cloud_colours_are_the_colour_vpc_image(colour_server: InProcessServer) -> None:
    stride = 4
    with colour_server.rig_client() as c:
        for _ in range(30):  # three responses of one frame (the worker keeps publishing)
            cloud, depth, vpc = c.pointcloud(stride), c.depth("npy"), c.frames("left", "vpc")
            if cloud.seq == depth.seq == vpc.seq:
                break
        else:
            raise AssertionError("could not fetch three responses of one frame")
    # The cloud has a point for each valid pixel of the stride grid, in row-major order.
    grid = np.isfinite(depth.depth[::stride, ::stride])
    expected = vpc.image[::stride, ::stride][grid][:, ::-1]  # BGR → the PLY's RGB
    assert cloud.colors is not None and cloud.colors.shape == expected.shape
    assert np.abs(cloud.colors.astype(int) - expected.astype(int)).mean() < 6.0  # the JPEG between
    assert np.mean(np.ptp(cloud.colors.astype(int), axis=1) > 10) > 0.2  # coloured, not gray points
