"""Image bombs: a small JPEG or PNG whose header declares 30000×30000 is refused from its header,
before a decoder allocates the image, wherever frames are decoded (live frames, recorded and bag
frames, ``rig process``); the declared size Pillow reads equals what OpenCV decodes."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from bench.image_bombs import bomb
from rig.capture.bag import BagRecording
from rig.capture.frame import Frame
from rig.errors import CorruptFrameError, RecordingError
from rig.image_size import MAX_FRAME_SIDE, declared_size, size_problem
from rig.recording import StoredFrame
from tests.helpers.recordings import encode

BOMB = (30000, 30000)


def _images() -> dict[str, bytes]:
    rng = np.random.default_rng(0)
    gray = (rng.random((240, 320)) * 255).astype(np.uint8)
    colour = (rng.random((120, 200, 3)) * 255).astype(np.uint8)
    deep = (rng.random((64, 96)) * 65535).astype(np.uint16)
    progressive = cv2.imencode(".jpg", colour, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes()
    return {
        "jpeg-gray": encode(gray, ".jpg"),
        "jpeg-colour": encode(colour, ".jpg", 90),
        "jpeg-progressive": progressive,
        "png-gray": encode(gray, ".png"),
        "png-colour": encode(colour, ".png"),
        "png-16bit": encode(deep, ".png"),
    }


@pytest.mark.parametrize("name", list(_images()))
def test_the_declared_size_is_what_opencv_decodes(name: str) -> None:
    data = _images()[name]
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img is not None
    assert declared_size(data, name.split("-")[0]) == (img.shape[1], img.shape[0])


def test_bombs_are_named_with_their_declared_size() -> None:
    images = _images()
    for fmt in ("jpeg", "png"):
        data = bomb(images[f"{fmt}-gray"], fmt)
        assert declared_size(data, fmt) == BOMB
        assert size_problem(data, fmt, (320, 240)) == (
            f"{fmt} header declares 30000x30000, the camera's frames are 320x240"
        )
        assert f"beyond the {MAX_FRAME_SIDE} px" in (size_problem(data, fmt, None) or "")
        assert size_problem(images[f"{fmt}-gray"], fmt, (320, 240)) is None
    assert "jpeg header unreadable" in (size_problem(b"\xff\xd8\xff\xd9", "jpeg", None) or "")


# Decoding in a fresh interpreter: its peak RSS (ru_maxrss) is the decode's, not the session's.
_DECODE = textwrap.dedent(
    """
    import json, resource, sys
    from pathlib import Path
    from rig.capture.frame import Frame
    from rig.errors import CorruptFrameError
    data, fmt, expected = Path(sys.argv[1]).read_bytes(), sys.argv[2], json.loads(sys.argv[3])
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    frame = Frame("left", 1, 0, fmt, 0, raw=data, expected_size=tuple(expected) if expected else None)
    try:
        _ = frame.gray
        outcome = "decoded"
    except CorruptFrameError as err:
        outcome = str(err)
    grown = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    print(json.dumps({"outcome": outcome, "grown_mb": grown}))
    """
)


@pytest.mark.parametrize("fmt", ["jpeg", "png"])
@pytest.mark.parametrize("expected", [(320, 240), None], ids=["camera-size", "no-size"])
def test_a_bomb_frame_is_refused_before_it_is_decoded(
    tmp_path: Path, fmt: str, expected: tuple[int, int] | None
) -> None:
    path = tmp_path / "bomb"
    path.write_bytes(bomb(_images()[f"{fmt}-gray"], fmt))
    run = subprocess.run(
        [sys.executable, "-c", _DECODE, str(path), fmt, json.dumps(expected)],
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    result = json.loads(run.stdout)
    print(f"{fmt} bomb, expected {expected}: {result}")
    assert "header declares 30000x30000" in result["outcome"], result
    assert result["grown_mb"] < 50, result  # a decode of it allocates 900 MB


def test_recorded_and_bag_frames_are_refused_by_their_header(tmp_path: Path) -> None:
    good = _images()["jpeg-gray"]
    stored = StoredFrame("jpeg", raw=bomb(good, "jpeg"), source="rec/frames/000001_l.jpg")
    with pytest.raises(RecordingError, match=r"rec/frames/000001_l\.jpg: .*declares 30000x30000, .* 320x240"):
        stored.pipeline_image((320, 240))
    with pytest.raises(RecordingError, match=r"declares 30000x30000, beyond"):
        stored.decoded()
    assert stored.declared_size() == BOMB
    assert StoredFrame("jpeg", raw=good).pipeline_image((320, 240)).shape == (240, 320)
    # A ROS bag's CompressedImage message is read through the same StoredFrame.
    ts = get_typestore(Stores.ROS2_HUMBLE)
    comp = "sensor_msgs/msg/CompressedImage"
    bag = tmp_path / "bombs"
    with Writer(bag, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {side: w.add_connection(f"/{side}/compressed", comp, typestore=ts) for side in ("l", "r")}
        for k, data in enumerate((good, bomb(good, "jpeg"))):
            stamp = ts.types["builtin_interfaces/msg/Time"](sec=1, nanosec=k * 10_000_000)
            header = ts.types["std_msgs/msg/Header"](stamp=stamp, frame_id="cam")
            for side in ("l", "r"):
                msg = ts.types[comp](header=header, format="jpeg", data=np.frombuffer(data, np.uint8))
                w.write(conns[side], 1_000_000_000 + k * 10_000_000, ts.serialize_cdr(msg, comp))
    recording = BagRecording(bag, "/l/compressed", "/r/compressed")
    first, second = recording.pairs
    assert recording.read_frame(first, "right").pipeline_image((320, 240)).shape == (240, 320)
    with pytest.raises(RecordingError, match=r"/r/compressed.*declares 30000x30000"):
        recording.read_frame(second, "right").pipeline_image((320, 240))


def test_a_live_frame_of_another_size_is_corrupt_not_decoded() -> None:
    good = _images()["png-gray"]
    frame = Frame("right", 7, 0, "png", 0, raw=bomb(good, "png", (640, 480)), expected_size=(320, 240))
    with pytest.raises(CorruptFrameError, match=r"camera right: frame 7: png header declares 640x480"):
        _ = frame.gray
    assert not frame.decoded
    assert Frame("right", 8, 0, "png", 0, raw=good, expected_size=(320, 240)).gray.shape == (240, 320)
