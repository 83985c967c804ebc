"""A rig of N cameras in ROS 2 terms (rig.ros.ring_messages, rig.ros.mcap_export.export_ring_mcap):
read back by rosbags' reader, every camera's raw frames and CameraInfo, each pair's depth under its
own namespace, the panorama and the fused cloud, one transform tree with every camera, pair and
the panorama; the two-camera names stay today's."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from rig.recording import Recording
from rig.rig_depth import process_sets
from rig.rig_pipeline import RigFrame, RigPipeline
from rig.ros.mcap_export import export_ring_mcap
from rig.ros.names import RosNames
from tests.helpers.rings import (
    SMALL_RING_CONFIG,
    SMALL_RING_PANORAMA_PX_PER_DEG,
    small_ring_preset,
    write_small_ring,
)

N = RosNames()
PAIRS = ["cam1-cam2", "cam2-cam3", "cam3-cam4", "cam4-cam1"]
CAMS = ["cam1", "cam2", "cam3", "cam4"]


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory, lut_cache: Path) -> tuple[Path, Path, RigPipeline]:
    base = tmp_path_factory.mktemp("ring-ros")
    rec = write_small_ring(base / "rec", frames=2)
    ring = RigPipeline(
        small_ring_preset().rig,
        SMALL_RING_CONFIG,
        cache_dir=lut_cache,
        panorama_px_per_deg=SMALL_RING_PANORAMA_PX_PER_DEG,
    )
    result = export_ring_mcap(Recording(rec), ring, base / "ring.mcap")
    assert result.pairs == 2 and not result.skipped
    return rec, base / "ring.mcap", ring


def read_all(path: Path) -> dict[str, list[Any]]:
    out: dict[str, list[Any]] = {}
    with AnyReader([path]) as reader:
        for conn, _, raw in reader.messages():
            out.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    return out


def test_the_names_of_a_pair_and_of_two_cameras() -> None:
    pair = N.for_pair("cam1-cam2")
    assert pair.depth_image == "/rig/cam1_cam2/depth/image_rect" and pair.points == "/rig/cam1_cam2/points"
    assert pair.rect_frame("cam1") == "rig_cam1_cam2_cam1_rect_optical_frame"
    assert pair.camera_frame("cam1") == N.camera_frame("cam1") == "rig_cam1_optical_frame"
    # Two cameras keep today's topics and frames.
    assert (N.depth_image, N.rect_frame("left"), N.points) == (
        "/rig/depth/image_rect",
        "rig_left_rect_optical_frame",
        "/rig/points",
    )
    assert N.panorama_image == "/rig/panorama/image"


def test_every_camera_pair_panorama_and_transform(exported: tuple[Path, Path, RigPipeline]) -> None:
    rec, path, ring = exported
    msgs = read_all(path)
    for cam in CAMS:
        assert len(msgs[N.raw_image(cam, compressed=False)]) == 2, cam  # rendered PNG frames: pixels
        info = msgs[N.raw_info(cam)][0]
        assert info.header.frame_id == N.camera_frame(cam) and info.width == ring.rig.cameras[cam].width
    for label in PAIRS:
        names = N.for_pair(label)
        for topic in (names.depth_image, names.range_image, names.points, names.depth_info):
            assert len(msgs[topic]) == 2, topic
    # The panorama and the fused cloud: exactly what the pipeline makes of the same sets.
    got: dict[int, RigFrame] = {}
    recording = Recording(rec)
    process_sets(ring, recording, recording.pairs, lambda s, f: got.__setitem__(s.seq, f))
    pano = msgs[N.panorama_image]
    assert len(pano) == 2 and pano[0].encoding == "32FC1" and pano[0].header.frame_id == N.panorama_frame
    image = np.frombuffer(pano[0].data, np.float32).reshape(pano[0].height, pano[0].width)
    assert np.array_equal(image, got[0].panorama.range, equal_nan=True)
    cloud = msgs[N.points][0]
    assert cloud.header.frame_id == N.rig_frame and cloud.width == np.isfinite(got[0].panorama.range).sum()
    children = {t.child_frame_id: t.header.frame_id for m in msgs[N.tf_static] for t in m.transforms}
    for cam in CAMS:
        assert children[N.camera_frame(cam)] == N.rig_frame
    for label in PAIRS:
        left, right = label.split("-")
        names = N.for_pair(label)
        assert children[names.rect_frame(left)] == N.camera_frame(left)
        assert children[names.rect_frame(right)] == N.camera_frame(right)
    assert children[N.panorama_frame] == N.rig_frame
