"""ROS bags as recordings: bags written by rosbags (an independent ROS 2 bag writer, sqlite3 and
MCAP storage) are paired by header stamp, read frame by frame, replayed by the file cameras and
turned into the same depth as the images they hold; bad bags are one clear error."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from rig.capture.bag import BagRecording, pair_stamps
from rig.capture.config import FileCameraConfig
from rig.capture.file_camera import FileCamera
from rig.capture.recorded import open_recording
from rig.errors import EndOfStream, RecordingError
from rig.recording import Recording
from rig.ros.mcap_export import export_mcap
from tests.rig.ros_fixtures import PERIOD_NS, T0_NS, pipeline, shot, write_jpeg_recording

TS = get_typestore(Stores.ROS2_HUMBLE)
LEFT, RIGHT = "/cam0/image_raw", "/cam1/image_raw/compressed"


def _header(stamp_ns: int, frame: str) -> Any:
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    t = TS.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
    return TS.types["std_msgs/msg/Header"](stamp=t, frame_id=frame)


def write_bag(
    path: Path,
    storage: StoragePlugin,
    *,
    left_stamps: list[int],
    right_stamps: list[int],
    left_topic: str = LEFT,
) -> tuple[list[np.ndarray[Any, Any]], list[bytes]]:
    """Left: raw mono8 images; right: JPEG CompressedImage; log time a little after the stamp."""
    s = shot()
    rng = np.random.default_rng(3)
    lefts, rights = [], []
    image_t, comp_t = "sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage"
    with Writer(path, version=8, storage_plugin=storage) as w:
        lc = w.add_connection(left_topic, image_t, typestore=TS)
        rc = w.add_connection(RIGHT, comp_t, typestore=TS)
        for t in left_stamps:
            img = np.clip(s.left.astype(int) + rng.integers(-2, 3, s.left.shape), 0, 255).astype(np.uint8)
            msg = TS.types[image_t](
                header=_header(t, "cam0"), height=img.shape[0], width=img.shape[1], encoding="mono8",
                is_bigendian=0, step=img.shape[1], data=img.reshape(-1),
            )  # fmt: skip
            w.write(lc, t + 1_000_000, TS.serialize_cdr(msg, image_t))
            lefts.append(img)
        for t in right_stamps:
            jpg = cv2.imencode(".jpg", s.right)[1].tobytes()
            msg = TS.types[comp_t](
                header=_header(t, "cam1"), format="jpeg", data=np.frombuffer(jpg, np.uint8)
            )
            w.write(rc, t + 3_000_000, TS.serialize_cdr(msg, comp_t))
            rights.append(jpg)
    return lefts, rights


STAMPS = [T0_NS + k * PERIOD_NS for k in range(4)]


@pytest.mark.parametrize("storage", [StoragePlugin.SQLITE3, StoragePlugin.MCAP])
def test_bag_pairs_by_header_stamp_and_reads_frames(tmp_path: Path, storage: StoragePlugin) -> None:
    # Right stamps 1.5 ms after the left, one extra right message with no partner.
    rights = [t + 1_500_000 for t in STAMPS] + [STAMPS[-1] + 3 * PERIOD_NS]
    lefts, jpegs = write_bag(tmp_path / "bag", storage, left_stamps=STAMPS, right_stamps=rights)
    for path in (tmp_path / "bag", next((tmp_path / "bag").glob("bag.*"))):  # the directory, the file
        rec = open_recording(path, left_topic=LEFT, right_topic=RIGHT)
        assert isinstance(rec, BagRecording)
        assert [(p.seq, p.left_ts_ns, p.right_ts_ns) for p in rec.pairs] == [
            (k, t, t + 1_500_000) for k, t in enumerate(STAMPS)
        ]
        for p in rec.pairs:
            left, right = rec.read_frame(p, "left"), rec.read_frame(p, "right")
            assert (
                left.format == "bgr" and left.image is not None and np.array_equal(left.image, lefts[p.seq])
            )
            assert right.format == "jpeg" and right.raw == jpegs[p.seq]
        rec.close()


def test_file_camera_replays_a_bag_through_the_camera_protocol(tmp_path: Path) -> None:
    write_bag(tmp_path / "bag", StoragePlugin.MCAP, left_stamps=STAMPS, right_stamps=STAMPS)
    frames = {}
    for cam in ("left", "right"):
        cfg = FileCameraConfig(
            recording=tmp_path / "bag", pace="fast", timestamps="recorded", left_topic=LEFT, right_topic=RIGHT
        )
        camera = FileCamera(cfg, cam)
        info = camera.info()
        assert (info.width, info.height) == (shot().left.shape[1], shot().left.shape[0])
        camera.open()
        got = []
        with pytest.raises(EndOfStream):
            while True:
                f = camera.read(1.0)
                assert f is not None
                got.append(f)
        frames[cam] = got
    assert [f.ts_ns for f in frames["left"]] == STAMPS == [f.ts_ns for f in frames["right"]]
    assert frames["left"][0].format == "bgr" and frames["right"][0].format == "jpeg"
    # Depth of the replayed frames equals depth of the images the bag holds.
    pipe = pipeline(tmp_path / "cache")
    depth = pipe.process(frames["left"][0].gray, frames["right"][0].gray).depth
    rec = open_recording(tmp_path / "bag", left_topic=LEFT, right_topic=RIGHT)
    first = rec.pairs[0]
    ref = pipe.process(
        rec.read_frame(first, "left").pipeline_image(), rec.read_frame(first, "right").pipeline_image()
    ).depth
    assert np.array_equal(depth, ref, equal_nan=True) and np.isfinite(depth).mean() > 0.5


def test_our_export_is_a_bag_we_read_back(tmp_path: Path) -> None:
    rec = write_jpeg_recording(tmp_path / "rec", pairs=2)
    export_mcap(Recording(rec.root), pipeline(tmp_path / "cache"), tmp_path / "out.mcap")
    bag = open_recording(
        tmp_path / "out.mcap",
        left_topic="/rig/left/image_raw/compressed",
        right_topic="/rig/right/image_raw/compressed",
    )
    assert [(p.left_ts_ns, p.right_ts_ns) for p in bag.pairs] == rec.stamps
    assert [bag.read_frame(p, "left").raw for p in bag.pairs] == [j[0] for j in rec.jpegs]


def test_pair_stamps_is_one_to_one_within_the_gate() -> None:
    left = [0, 100, 200, 300]
    right = [5, 95, 160, 400]
    assert pair_stamps(left, right, 10) == [(0, 0), (1, 1)]
    assert pair_stamps(left, right, 60) == [(0, 0), (1, 1), (2, 2)]
    # 150 is as near to 100 as to 200: it pairs with neither 200 (not its nearest) nor 100
    # (whose nearest is 95), and no message pairs twice.
    assert pair_stamps(left, [5, 95, 150, 400], 60) == [(0, 0), (1, 1)]


def test_bag_errors_are_one_clear_line(tmp_path: Path) -> None:
    write_bag(tmp_path / "bag", StoragePlugin.MCAP, left_stamps=STAMPS, right_stamps=STAMPS)
    expected = r"no topic '/cam9/image_raw' \(left camera\); image topics in the bag: /cam0/image_raw, /cam1/"
    with pytest.raises(RecordingError, match=expected):
        open_recording(tmp_path / "bag", left_topic="/cam9/image_raw", right_topic=RIGHT)
    with pytest.raises(RecordingError, match="name its two image topics"):
        open_recording(tmp_path / "bag")
    # Unsynchronised: the right camera's stamps 0.4 s off.
    write_bag(
        tmp_path / "off",
        StoragePlugin.MCAP,
        left_stamps=STAMPS,
        right_stamps=[t + 400_000_000 for t in STAMPS],
    )
    with pytest.raises(
        RecordingError, match=r"are not synchronised: 0 of 4 messages .*median offset 350\.0 ms"
    ):
        open_recording(tmp_path / "off", left_topic=LEFT, right_topic=RIGHT)
    # Truncated: the MCAP file cut in half.
    src = next((tmp_path / "bag").glob("*.mcap"))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(src.read_bytes()[: src.stat().st_size // 2])
    with pytest.raises(RecordingError, match=r"cut\.mcap: truncated or corrupt bag"):
        open_recording(cut, left_topic=LEFT, right_topic=RIGHT)
    with pytest.raises(RecordingError, match="not found"):
        open_recording(tmp_path / "missing.mcap", left_topic=LEFT, right_topic=RIGHT)
