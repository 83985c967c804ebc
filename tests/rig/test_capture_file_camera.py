"""FileCamera: replay semantics (timestamps, pacing, loop) and every fault, frame by frame."""

from __future__ import annotations

import itertools
import math
import threading
import time
from pathlib import Path

import pytest
from pydantic import ValidationError

from rig.capture.faults import parse_fault
from rig.capture.file_camera import FileCamera
from rig.capture.frame import Frame, encoded_problem
from rig.capture.protocol import TimeBase
from rig.errors import CameraUnavailable, ConfigError, EndOfStream, RecordingError
from rig.recording import Recording
from tests.helpers.recordings import PERIOD_NS, T0_NS, file_camera_config, write_recording


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_recording(tmp_path_factory.mktemp("fc") / "rec", 12, right_skew_ns=2_000_000)


def read_all(cam: FileCamera, limit: int = 1000, timeout_s: float = 2.0) -> list[Frame]:
    frames = []
    try:
        while len(frames) < limit:
            f = cam.read(timeout_s)
            if f is not None:
                frames.append(f)
    except EndOfStream:
        pass
    return frames


def read_n(cam: FileCamera, n: int, timeout_s: float = 2.0) -> list[Frame]:
    out: list[Frame] = []
    while len(out) < n:
        f = cam.read(timeout_s)
        if f is not None:
            out.append(f)
    return out


def test_recorded_timestamps_are_verbatim_and_bytes_exact(rec: Path) -> None:
    cam = FileCamera(file_camera_config(rec, "right", pace="fast", timestamps="recorded"), "right")
    cam.open()
    frames = read_all(cam)
    r = Recording(rec)
    assert [(f.seq, f.ts_ns) for f in frames] == [(p.seq, p.right_ts_ns) for p in r.pairs]
    for f, p in zip(frames, r.pairs, strict=True):
        assert f.raw == (rec / p.right_file).read_bytes()
        assert f.format == "jpeg" and f.camera == "right"
    with pytest.raises(EndOfStream):
        cam.read(0.1)
    info = cam.info()
    assert (info.width, info.height, info.timestamp_source, info.host_clock) == (160, 120, "recorded", False)
    assert cam.nominal_fps == pytest.approx(1e9 / PERIOD_NS)


def test_live_timestamps_follow_the_schedule_and_loop(rec: Path) -> None:
    base = TimeBase()
    cams = {
        n: FileCamera(
            file_camera_config(rec, n, pace="recorded", loop=True, timestamps="live"), n, timebase=base
        )
        for n in ("left", "right")
    }
    for c in cams.values():
        c.open()
    # Read both as their capture threads would, in step (a camera read late loses frames).
    left, right = [], []
    for _ in range(30):
        left += read_n(cams["left"], 1)
        right += read_n(cams["right"], 1)
    anchor = base.anchor_ns()
    span = 12 * PERIOD_NS  # one loop: the left column spans 11 periods, plus one
    for k, (lf, rf) in enumerate(zip(left, right, strict=True)):
        loops, i = divmod(k, 12)
        assert lf.seq == rf.seq == k  # seq keeps increasing across loops
        assert lf.ts_ns == anchor + i * PERIOD_NS + loops * span
        assert rf.ts_ns - lf.ts_ns == 2_000_000  # the recorded skew survives rebasing
        assert lf.host_ns >= lf.ts_ns  # never delivered before it is due
    assert cams["left"].info().host_clock


def test_fixed_fps_pace(rec: Path) -> None:
    cam = FileCamera(file_camera_config(rec, "left", pace=100.0, timestamps="live"), "left")
    cam.open()
    frames = read_all(cam)
    assert [f.seq for f in frames] == list(range(12))
    assert {b.ts_ns - a.ts_ns for a, b in itertools.pairwise(frames)} == {10_000_000}
    assert cam.nominal_fps == pytest.approx(100.0)


def test_config_errors(rec: Path, tmp_path: Path) -> None:
    with pytest.raises(ValidationError, match="paced replay"):
        file_camera_config(rec, pace="fast", timestamps="live")
    with pytest.raises(ConfigError, match="no camera 'middle'"):
        FileCamera(file_camera_config(rec, "middle"), "left")
    with pytest.raises(RecordingError, match=r"recording\.json"):
        FileCamera(file_camera_config(tmp_path), "left")
    empty = write_recording(tmp_path / "empty", 0)
    with pytest.raises(RecordingError, match="no frames"):
        FileCamera(file_camera_config(empty), "left")


def test_missing_frame_file_is_a_corrupt_frame_not_a_crash(tmp_path: Path) -> None:
    from rig.errors import CorruptFrameError

    src = write_recording(tmp_path / "rec", 3)
    (src / "left" / "000001.jpg").unlink()
    cam = FileCamera(file_camera_config(src, pace="fast", timestamps="recorded"), "left")
    cam.open()
    assert cam.read(1).seq == 0  # type: ignore[union-attr]
    with pytest.raises(CorruptFrameError, match="frame 1"):
        cam.read(1)
    assert cam.read(1).seq == 2  # type: ignore[union-attr]
    assert cam.stats().unreadable == 1


# ----- faults, one by one ------------------------------------------------------------------------
def fast_cam(rec: Path, *faults: dict[str, object], loop: bool = True) -> FileCamera:
    cam = FileCamera(
        file_camera_config(rec, "left", pace="fast", loop=loop, timestamps="recorded", faults=list(faults)),
        "left",
    )
    cam.open()
    return cam


def test_drop_and_rate_faults_lose_exact_frames(rec: Path) -> None:
    cam = fast_cam(
        rec, {"kind": "drop", "at_frame": 2, "count": 3}, {"kind": "rate", "at_frame": 4, "frames": 6}
    )
    seqs = [f.seq for f in read_n(cam, 6)]
    # 0,1 delivered; 2,3,4 dropped; 5,6 delivered (4 delivered → rate starts): keep 7, lose 8, keep 9 ...
    assert seqs == [0, 1, 5, 6, 7, 9]
    assert read_n(cam, 3)[0].seq == 11
    assert cam.stats().lost == 3 + 3


def test_corrupt_and_truncate_faults(rec: Path) -> None:
    cam = fast_cam(rec, {"kind": "corrupt", "at_frame": 1, "count": 2}, {"kind": "truncate", "at_frame": 3})
    frames = read_n(cam, 5)
    originals = [(rec / f"left/{k:06d}.jpg").read_bytes() for k in range(5)]
    assert frames[0].raw == originals[0] and frames[4].raw == originals[4]
    for f in frames[1:3]:
        assert f.raw is not None and len(f.raw) == len(originals[f.seq])
        assert encoded_problem(f.raw, "jpeg") is not None
    assert frames[3].raw == originals[3][: len(originals[3]) // 2]
    s = cam.stats()
    assert (s.corrupted, s.truncated, s.lost) == (2, 1, 0)


def test_timestamp_jump_lasts_until_reopen(rec: Path) -> None:
    cam = fast_cam(rec, {"kind": "timestamp_jump", "at_frame": 2, "offset_ms": -1500})
    frames = read_n(cam, 4)
    assert [f.ts_ns for f in frames] == [
        T0_NS + k * PERIOD_NS - (1_500_000_000 if k >= 2 else 0) for k in range(4)
    ]
    cam.close()
    cam.open()
    assert cam.read(1).ts_ns == T0_NS + 4 * PERIOD_NS  # type: ignore[union-attr]


def test_disconnect_then_reappear(rec: Path) -> None:
    cam = FileCamera(file_camera_config(rec, "left", pace=50.0, loop=True, timestamps="live"), "left")
    cam.open()
    first = read_n(cam, 2)
    cam.inject(parse_fault({"kind": "disconnect", "duration_s": 0.3}))
    with pytest.raises(CameraUnavailable, match="disconnected"):
        cam.read(1.0)
    with pytest.raises(CameraUnavailable, match="not open"):
        cam.read(0.1)
    reopened = False
    for _ in range(200):
        try:
            cam.open()
            reopened = True
            break
        except CameraUnavailable as err:
            assert "disconnected" in str(err)
            time.sleep(0.02)
    assert reopened
    nxt = read_n(cam, 1)[0]
    s = cam.stats()
    # Frames due while disconnected are lost: exactly the gap in seq.
    assert nxt.seq - first[-1].seq - 1 == s.lost > 0
    assert s.disconnects == 1


def test_stall_on_a_paced_camera_loses_the_frames_due_during_it(rec: Path) -> None:
    duration = 0.21  # 6.3 periods at 30 fps: frames due at +0 .. +6 periods are lost
    cam = FileCamera(
        file_camera_config(
            rec,
            "left",
            pace="recorded",
            loop=True,
            timestamps="live",
            faults=[{"kind": "stall", "at_frame": 3, "duration_s": duration}],
        ),
        "left",
    )
    cam.open()
    got = read_n(cam, 3)
    assert cam.read(0.05) is None  # stalled: nothing within the timeout
    after = read_n(cam, 1)[0]
    expected = math.ceil(duration * 1e9 / PERIOD_NS)
    assert after.seq - got[-1].seq - 1 == expected == cam.stats().lost


def test_stall_on_a_fast_camera_only_pauses(rec: Path) -> None:
    cam = fast_cam(rec, {"kind": "stall", "at_frame": 2, "duration_s": 0.2})
    got = read_n(cam, 2)
    assert cam.read(0.01) is None
    assert [f.seq for f in got + read_n(cam, 2)] == [0, 1, 2, 3]
    assert cam.stats().lost == 0


def test_runtime_inject_wakes_a_waiting_reader(rec: Path) -> None:
    cam = FileCamera(file_camera_config(rec, "left", pace=2.0, loop=True, timestamps="live"), "left")
    cam.open()
    read_n(cam, 1)  # next frame is due in 0.5 s
    errors: list[BaseException] = []

    def reader() -> None:
        try:
            cam.read(5.0)
        except CameraUnavailable as err:
            errors.append(err)

    t = threading.Thread(target=reader)
    t.start()
    time.sleep(0.05)
    cam.inject({"kind": "disconnect", "duration_s": 1.0})
    t.join(3.0)
    assert not t.is_alive() and errors and "disconnected" in str(errors[0])


def test_at_s_trigger(rec: Path) -> None:
    cam = FileCamera(
        file_camera_config(
            rec,
            "left",
            pace=50.0,
            loop=True,
            timestamps="live",
            faults=[{"kind": "drop", "at_s": 0.1, "count": 2}],
        ),
        "left",
    )
    cam.open()
    seqs = [f.seq for f in read_n(cam, 12)]
    gaps = [b - a for a, b in itertools.pairwise(seqs)]
    assert sorted(gaps)[-1] == 3 and gaps.count(1) == len(gaps) - 1  # one gap of two lost frames
    assert cam.stats().lost == 2


def test_fault_validation() -> None:
    with pytest.raises(ValidationError, match="not both"):
        parse_fault({"kind": "stall", "duration_s": 1, "at_frame": 1, "at_s": 1})
    with pytest.raises(ValidationError, match="exactly one"):
        parse_fault({"kind": "rate", "factor": 0.5})
    with pytest.raises(ValidationError):
        parse_fault({"kind": "meteor"})
    with pytest.raises(ValidationError, match="must not be 0"):
        parse_fault({"kind": "timestamp_jump", "offset_ms": 0})
    assert parse_fault({"kind": "rate", "factor": 0.25, "frames": 8}).keep_every == 4  # type: ignore[union-attr]
