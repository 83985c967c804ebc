"""MCAP export in ROS 2's profile, read back by independent readers (rosbags' bag reader and the
mcap-ros2 decoder): counts, bytes, depth, camera infos, transforms and the point cloud."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from scipy.spatial.transform import Rotation

from calibration.geometry import invert_transform, make_transform
from rig.depth import depth_to_png_mm
from rig.pipeline import DepthPipeline
from rig.recording import Recording
from rig.ros.mcap_export import export_mcap
from rig.ros.names import RosNames
from tests.rig.ros_fixtures import PAIRS, TinyRecording, pipeline, shot, write_jpeg_recording

N = RosNames()


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> tuple[TinyRecording, Path, DepthPipeline]:
    base = tmp_path_factory.mktemp("export")
    rec = write_jpeg_recording(base / "rec")
    pipe = pipeline(base / "cache")
    result = export_mcap(Recording(rec.root), pipe, base / "out.mcap")
    assert result.pairs == PAIRS and not result.skipped
    assert not (base / "out.mcap.partial").exists()
    return rec, base / "out.mcap", pipe


def read_all(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """topic → [(log time, message)] through rosbags' reader (its own CDR and .msg parser)."""
    out: dict[str, list[tuple[int, Any]]] = {}
    with AnyReader([path]) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    return out


def stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def test_topics_counts_stamps_and_jpeg_bytes(exported: tuple[TinyRecording, Path, DepthPipeline]) -> None:
    rec, path, _ = exported
    msgs = read_all(path)
    per_pair = [
        N.raw_image("left", compressed=True), N.raw_info("left"), N.raw_image("right", compressed=True),
        N.raw_info("right"), N.rect_image("left"), N.rect_image("right"), N.rect_info("left"),
        N.rect_info("right"), N.depth_image, N.depth_info, N.range_image, N.confidence_image, N.points,
    ]  # fmt: skip
    assert {t: len(v) for t, v in msgs.items()} == {**{t: PAIRS for t in per_pair}, "/tf_static": 1}
    for k, (lts, rts) in enumerate(rec.stamps):
        left = msgs[N.raw_image("left", compressed=True)][k][1]
        right = msgs[N.raw_image("right", compressed=True)][k][1]
        assert left.format == "jpeg" and bytes(left.data) == rec.jpegs[k][0]
        assert bytes(right.data) == rec.jpegs[k][1]
        assert (stamp(left), stamp(right)) == (lts, rts)
        assert msgs[N.raw_image("left", compressed=True)][k][0] == lts  # log time = capture time
        assert stamp(msgs[N.depth_image][k][1]) == lts
        assert msgs[N.depth_image][k][1].header.frame_id == N.rect_frame("left")
    assert msgs[N.points][0][1].header.frame_id == N.rig_frame


def test_depth_range_and_confidence_equal_the_pipeline(
    exported: tuple[TinyRecording, Path, DepthPipeline],
) -> None:
    rec, path, pipe = exported
    msgs = read_all(path)
    for k in range(PAIRS):
        left = cv2.imdecode(np.frombuffer(rec.jpegs[k][0], np.uint8), cv2.IMREAD_UNCHANGED)
        right = cv2.imdecode(np.frombuffer(rec.jpegs[k][1], np.uint8), cv2.IMREAD_UNCHANGED)
        frame = pipe.process(left, right)
        img = msgs[N.depth_image][k][1]
        assert (img.encoding, img.is_bigendian, img.step) == ("32FC1", 0, 4 * img.width)
        depth = np.frombuffer(img.data, "<f4").reshape(img.height, img.width)
        assert np.array_equal(depth, frame.depth, equal_nan=True)
        assert np.count_nonzero(np.isfinite(depth)) > 0.5 * depth.size
        conf = msgs[N.confidence_image][k][1]
        assert frame.confidence is not None
        assert np.array_equal(np.frombuffer(conf.data, "<f4").reshape(depth.shape), frame.confidence)
    # Range: each valid pixel's distance from the left VPC's centre, from the point cloud's
    # points (an independent path: pixel rays scaled to depth and moved into the rig frame).
    rng_msg = msgs[N.range_image][0][1]
    rng = np.frombuffer(rng_msg.data, "<f4").reshape(rng_msg.height, rng_msg.width)
    cloud = msgs[N.points][0][1]
    pts = decode_cloud(cloud)
    centre = pipe.pair.T_rig_rect["left"][:3, 3]
    valid = np.isfinite(rng)
    dist = np.linalg.norm(np.stack([pts["x"], pts["y"], pts["z"]], 1).astype(np.float64) - centre, axis=1)
    np.testing.assert_allclose(rng[valid], dist, rtol=1e-5)
    assert np.all(
        rng[valid] >= np.frombuffer(msgs[N.depth_image][0][1].data, "<f4").reshape(rng.shape)[valid]
    )


def decode_cloud(cloud: Any) -> np.ndarray[Any, Any]:
    """A PointCloud2 by its own field table (names, offsets, FLOAT32 = 7)."""
    assert cloud.height == 1 and not cloud.is_bigendian and cloud.row_step == cloud.width * cloud.point_step
    fields = {f.name: (f.offset, f.datatype) for f in cloud.fields}
    assert set(fields) == {"x", "y", "z", "rgb"} and all(dt == 7 for _, dt in fields.values())
    offsets = [o for o, _ in fields.values()]
    dtype = np.dtype(
        {"names": list(fields), "formats": ["<f4"] * 4, "offsets": offsets, "itemsize": cloud.point_step}
    )
    return np.frombuffer(bytes(cloud.data), dtype)


def test_point_cloud_is_the_pipelines_in_the_rig_frame(
    exported: tuple[TinyRecording, Path, DepthPipeline],
) -> None:
    rec, path, pipe = exported
    cloud = read_all(path)[N.points][0][1]
    pts = decode_cloud(cloud)
    left = cv2.imdecode(np.frombuffer(rec.jpegs[0][0], np.uint8), cv2.IMREAD_UNCHANGED)
    right = cv2.imdecode(np.frombuffer(rec.jpegs[0][1], np.uint8), cv2.IMREAD_UNCHANGED)
    ref, colors = pipe.point_cloud(pipe.process(left, right))
    assert np.array_equal(np.stack([pts["x"], pts["y"], pts["z"]], 1), ref)
    rgb = pts["rgb"].view("<u4")  # PCL's packed colour: 0xAARRGGBB
    got = np.stack([(rgb >> 16) & 255, (rgb >> 8) & 255, rgb & 255], 1)
    assert np.array_equal(got, colors) and np.all(rgb >> 24 == 255)
    # The rendered plane (5 baselines ahead of the rig) where it is.
    truth = float(np.nanmedian(shot().depth))
    assert abs(float(np.median(pts["z"])) - truth) < 0.02 * truth


def test_transforms_rebuild_the_calibration(exported: tuple[TinyRecording, Path, DepthPipeline]) -> None:
    _, path, pipe = exported
    tf = read_all(path)["/tf_static"][0][1]
    T: dict[tuple[str, str], np.ndarray[Any, Any]] = {}
    for t in tf.transforms:
        q, p = t.transform.rotation, t.transform.translation
        R = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
        T[(t.header.frame_id, t.child_frame_id)] = make_transform(R, [p.x, p.y, p.z])
    body = T[(N.body_frame, N.rig_frame)]
    # REP 103: the optical z (forward) is the body's x, optical x (right) the body's -y.
    np.testing.assert_allclose(body[:3, :3] @ [0, 0, 1], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(body[:3, :3] @ [1, 0, 0], [0, -1, 0], atol=1e-12)
    for cam in ("left", "right"):
        T_rig_cam = T[(N.rig_frame, N.camera_frame(cam))]
        np.testing.assert_allclose(T_rig_cam, pipe.rig.T_rig_cam[cam], atol=1e-12)
        T_rig_rect = T_rig_cam @ T[(N.camera_frame(cam), N.rect_frame(cam))]
        np.testing.assert_allclose(T_rig_rect, pipe.pair.T_rig_rect[cam], atol=1e-12)


def test_rectified_camera_infos_reproduce_our_projection(
    exported: tuple[TinyRecording, Path, DepthPipeline],
) -> None:
    _, path, pipe = exported
    msgs = read_all(path)
    pair = pipe.pair
    rng = np.random.default_rng(1)
    pts_left = rng.uniform([-3, -2, 2], [3, 2, 9], size=(200, 3))  # in the left rectified frame
    T_right_left = invert_transform(pair.T_rig_rect["right"]) @ pair.T_rig_rect["left"]
    pts_right = pts_left @ T_right_left[:3, :3].T + T_right_left[:3, 3]
    for cam, pts in (("left", pts_left), ("right", pts_right)):
        info = msgs[N.rect_info(cam)][0][1]
        assert info.distortion_model == "plumb_bob" and np.all(np.asarray(info.d) == 0)
        assert np.array_equal(np.asarray(info.r).reshape(3, 3), np.eye(3))
        P = np.asarray(info.p).reshape(3, 4)
        np.testing.assert_allclose(P[:, :3], np.asarray(info.k).reshape(3, 3))
        # ROS: P projects points of the *first* (left) rectified frame, Tx = -fx·B for the right.
        uvw = np.c_[pts_left, np.ones(len(pts_left))] @ P.T
        ours, ok = pair.camera.project(pts, in_image=False)
        assert ok.all()
        np.testing.assert_allclose(uvw[:, :2] / uvw[:, 2:], ours, atol=1e-9)
    assert msgs[N.depth_info][0][1].header.frame_id == N.rect_frame("left")


def test_raw_camera_info_rebuilds_our_rectification_in_opencv(
    exported: tuple[TinyRecording, Path, DepthPipeline],
) -> None:
    """OpenCV's fisheye undistort-rectify maps from the raw CameraInfo (equidistant D, K, R, P)
    equal our LUT wherever OpenCV's fisheye model reaches (rays under 90° off the lens axis)."""
    _, path, pipe = exported
    msgs = read_all(path)
    for cam in ("left", "right"):
        info = msgs[N.raw_info(cam)][0][1]
        assert info.distortion_model == "equidistant" and len(info.d) == 4
        K, R = np.asarray(info.k).reshape(3, 3), np.asarray(info.r).reshape(3, 3)
        P = np.asarray(info.p).reshape(3, 4)
        size = (pipe.pair.camera.width, pipe.pair.camera.height)
        mx, my = cv2.fisheye.initUndistortRectifyMap(K, np.asarray(info.d), R, P[:, :3], size, cv2.CV_32FC1)
        lut = pipe.luts[cam]
        u, v = np.meshgrid(np.arange(size[0]), np.arange(size[1]))
        c = pipe.pair.camera
        rays = (
            np.stack([(u - c.cx) / c.fx, (v - c.cy) / c.fy, np.ones(u.shape)], -1)
            @ pipe.pair.R_cam_rect[cam].T
        )
        off_axis = np.degrees(np.arctan2(np.hypot(rays[..., 0], rays[..., 1]), rays[..., 2]))
        use = lut.valid & (off_axis < 85.0)
        assert use.mean() > 0.5
        worst = float(max(np.abs(mx[use] - lut.map_x[use]).max(), np.abs(my[use] - lut.map_y[use]).max()))
        print(
            f"\n{cam}: OpenCV's fisheye maps from CameraInfo vs our LUT within 85° off axis: {worst:.1e} px"
        )
        assert worst <= 1e-3  # measured 0 (docs/ros.md): the same float32 maps


def test_ros2_profile_as_ros2_bag_writes_it(exported: tuple[TinyRecording, Path, DepthPipeline]) -> None:
    _, path, _ = exported
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None
        for ch in summary.channels.values():
            assert ch.message_encoding == "cdr"
            assert summary.schemas[ch.schema_id].encoding == "ros2msg"
            (qos,) = yaml.safe_load(ch.metadata["offered_qos_profiles"])
            assert qos["reliability"] == 1
            assert qos["durability"] == (1 if ch.topic == "/tf_static" else 2)  # transient local / volatile
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        bag = yaml.safe_load(meta["rosbag2"]["serialized_metadata"])
        counts = {t["topic_metadata"]["name"]: t["message_count"] for t in bag["topics_with_message_count"]}
        assert counts[N.depth_image] == PAIRS and bag["storage_identifier"] == "mcap"
        assert bag["message_count"] == sum(summary.statistics.channel_message_counts.values())
        # The mcap-ros2 decoder (its own CDR and .msg parser) reads every message too.
        decoded = {}
        for _, ch, _, msg in reader.iter_decoded_messages():
            decoded.setdefault(ch.topic, []).append(msg)
        depth = decoded[N.depth_image][0]
        assert (depth.encoding, depth.width, depth.height) == ("32FC1", 160, 120)


def test_16uc1_depth_is_millimetres(tmp_path: Path) -> None:
    rec = write_jpeg_recording(tmp_path / "rec", pairs=1)
    pipe = pipeline(tmp_path / "cache")
    names = RosNames(depth_encoding="16UC1", namespace="/front", frame_prefix="front")
    export_mcap(Recording(rec.root), pipe, tmp_path / "mm.mcap", names=names, rectified_images=False)
    msgs = read_all(tmp_path / "mm.mcap")
    assert "/front/rect/left/image_rect" not in msgs and "/front/rect/left/camera_info" in msgs
    img = msgs["/front/depth/image_rect"][0][1]
    assert img.encoding == "16UC1" and img.header.frame_id == "front_left_rect_optical_frame"
    left = cv2.imdecode(np.frombuffer(rec.jpegs[0][0], np.uint8), cv2.IMREAD_UNCHANGED)
    right = cv2.imdecode(np.frombuffer(rec.jpegs[0][1], np.uint8), cv2.IMREAD_UNCHANGED)
    mm = np.frombuffer(img.data, "<u2").reshape(img.height, img.width)
    assert np.array_equal(mm, depth_to_png_mm(pipe.process(left, right).depth))


def test_export_of_unreadable_frames_leaves_nothing(tmp_path: Path) -> None:
    rec = write_jpeg_recording(tmp_path / "rec", pairs=2)
    for p in (tmp_path / "rec" / "left").iterdir():
        p.write_bytes(b"not a jpeg")
    out = tmp_path / "out.mcap"
    from rig.errors import RecordingError

    with pytest.raises(RecordingError, match="no pair of 2 could be processed"):
        export_mcap(Recording(rec.root), pipeline(tmp_path / "cache"), out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache", "rec"]
    assert shot().left.shape == (240, 320)
