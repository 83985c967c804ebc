"""The pinhole depth (rig.pinhole_depth) of the default lat-lon pair on the topics ROS tools read:
live on Foxglove (read by a foxglove.websocket.v1 client with the schemas the server advertised)
and in ``rig export``'s MCAP (read by rosbags, its own CDR and .msg parser). Both checked as
depth_image_proc would use them: z on a plumb_bob pinhole with zero distortion, against the
renderer's exact depth of that pinhole."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from calibration.formats.api import load_rig
from rig.capture.recorded import open_recording
from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPairConfig
from rig.ros.mcap_export import export_mcap
from rig.ros.names import RosNames
from rig.stereo import StereoParams
from service.settings import load_settings
from tests.helpers.service import SMALL_SPEC, SmallRecording, in_process, service_overrides
from tests.service.foxglove_client import FoxgloveClient

pytestmark = pytest.mark.timeout(240)

N = RosNames()
LATLON = RectifiedPairConfig(projection="latlon", px_per_deg=2.8)
WIDTH, HEIGHT, HFOV = SMALL_SPEC.vpc.pinhole_size  # the recording's ground truth: its left pinhole


def check_against_truth(
    z: np.ndarray[Any, Any], fx: float, baseline_m: float, gt: np.ndarray[Any, Any]
) -> None:
    """Within the bounds the pinhole pair's own depth meets (a disparity error, in pixels)."""
    assert z.shape == gt.shape == (HEIGHT, WIDTH)
    both = np.isfinite(z) & np.isfinite(gt)
    fb = fx * baseline_m
    err_px = np.abs(fb / z[both] - fb / gt[both])
    print(f"\npinhole depth: {100 * both.mean():.0f} % of the pixels, median {np.median(err_px):.2f} px")
    assert both.mean() > 0.4 and np.median(err_px) < 0.35 and np.mean(err_px < 1.0) > 0.85


def check_info(distortion: str, d: list[float], k: list[float], size: tuple[int, int], frame: str) -> float:
    assert distortion == "plumb_bob" and list(d) == [0.0] * 5
    assert size == (WIDTH, HEIGHT) and frame == N.rect_frame("left")
    fx = float(k[0])
    assert fx == pytest.approx((WIDTH / 2) / np.tan(np.radians(HFOV) / 2)) and k[4] == fx
    return fx


def test_foxglove_publishes_the_pinhole_depth(
    small_recording: SmallRecording, lut_cache: Path, tmp_path: Path
) -> None:
    doc = service_overrides(small_recording.loop, tmp_path, lut_cache)
    doc["server"]["foxglove"] = {"enabled": True, "port": 0, "max_fps": 10.0}
    doc["rectified"] = LATLON.model_dump()
    doc["pinhole_depth"] = {"width": WIDTH, "height": HEIGHT, "hfov_deg": HFOV}
    topics = [N.pinhole_depth_image, N.pinhole_depth_info]
    with in_process(load_settings(None, doc)) as server:
        client = FoxgloveClient(server.app.state.foxglove.port)
        try:
            client.subscribe(topics)
            assert client.channels[N.pinhole_depth_image].schema_name == "foxglove.RawImage"
            got: dict[str, Any] = {}
            deadline = time.monotonic() + 60
            while len(got) < len(topics):
                assert time.monotonic() < deadline, list(got)
                topic, _, msg = client.next_message()
                got[topic] = msg
        finally:
            client.close()
        baseline = server.runtime.pipeline.pair.baseline_m
    info, image = got[N.pinhole_depth_info], got[N.pinhole_depth_image]
    fx = check_info(
        info.distortion_model, list(info.D), list(info.K), (info.width, info.height), info.frame_id
    )
    assert image.encoding == "32FC1" and image.frame_id == N.rect_frame("left")
    z = np.frombuffer(image.data, "<f4").reshape(image.height, image.width)
    check_against_truth(z, fx, baseline, small_recording.gt_depth)


def test_the_mcap_export_carries_the_pinhole_depth(
    small_recording: SmallRecording, lut_cache: Path, tmp_path: Path
) -> None:
    recording = open_recording(small_recording.loop)
    pipe = DepthPipeline(
        load_rig(recording.calibration_path), LATLON, StereoParams(disparity_range=64), cache_dir=lut_cache
    )
    from rig.pinhole_depth import PinholeDepthConfig

    config = PinholeDepthConfig(width=WIDTH, height=HEIGHT, hfov_deg=HFOV)
    result = export_mcap(recording, pipe, tmp_path / "out.mcap", pinhole_depth=config)
    assert result.pairs == len(recording.pairs) and not result.skipped
    got: dict[str, list[Any]] = {}
    with AnyReader([tmp_path / "out.mcap"]) as reader:
        for conn, _, raw in reader.messages():
            if conn.topic in (N.pinhole_depth_image, N.pinhole_depth_info):
                got.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    assert len(got[N.pinhole_depth_image]) == len(got[N.pinhole_depth_info]) == result.pairs
    info = got[N.pinhole_depth_info][0]
    size = (int(info.width), int(info.height))
    fx = check_info(info.distortion_model, list(info.d), list(info.k), size, info.header.frame_id)
    image = got[N.pinhole_depth_image][0]
    assert image.encoding == "32FC1" and image.header.frame_id == N.rect_frame("left")
    z = np.frombuffer(bytes(image.data), "<f4").reshape(image.height, image.width)
    check_against_truth(z, fx, pipe.pair.baseline_m, small_recording.gt_depth)


def test_a_pinhole_pair_publishes_no_second_depth(small_recording: SmallRecording, lut_cache: Path) -> None:
    """On a pinhole pair the depth topic already is z on a pinhole: no pinhole depth topic."""
    from rig.ros.messages import MessageBuilder

    recording = open_recording(small_recording.loop)
    pipe = DepthPipeline(
        load_rig(recording.calibration_path),
        SMALL_SPEC.vpc,
        StereoParams(disparity_range=64),
        cache_dir=lut_cache,
    )
    left, right = (recording.read_frame(recording.pairs[0], c).decoded() for c in recording.cameras[:2])
    topics = {m.topic for m in MessageBuilder(pipe).depth_outputs(pipe.process(left, right), 0)}
    assert N.depth_image in topics and N.pinhole_depth_image not in topics
