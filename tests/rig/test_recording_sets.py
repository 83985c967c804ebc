"""Recordings of N cameras (rig.recording, rig.frame_sets): a folder and two columns per camera,
the two-camera recording byte for byte today's, crash safety per set, one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import rig.recording
from rig.capture.file_camera import FileCamera
from rig.errors import DiskFullError, RecordingError
from rig.frame_sets import FRAMES_HEADER, FrameSetRecord, frames_header
from rig.recording import Recording, RecordingWriter
from tests.helpers.recordings import (
    PERIOD_NS,
    T0_NS,
    encode,
    file_camera_config,
    frame_image,
    write_recording,
    write_set_recording,
)
from tests.reliability.fake_disk import Budget, limited_open

RING = ("cam1", "cam2", "cam3", "cam4")


def test_two_camera_recordings_keep_todays_bytes(tmp_path: Path) -> None:
    assert FRAMES_HEADER == ("seq", "left_ts_ns", "right_ts_ns", "left_file", "right_file")
    root = write_recording(tmp_path / "rec", 2, right_skew_ns=7)
    lines = (root / "frames.csv").read_text().splitlines()
    assert lines == [
        "seq,left_ts_ns,right_ts_ns,left_file,right_file",
        f"0,{T0_NS},{T0_NS + 7},left/000000.jpg,right/000000.jpg",
        f"1,{T0_NS + PERIOD_NS},{T0_NS + PERIOD_NS + 7},left/000001.jpg,right/000001.jpg",
    ]
    assert json.loads((root / "recording.json").read_text())["cameras"] == ["left", "right"]
    p = Recording(root).pairs[1]
    assert (p.left_ts_ns, p.right_ts_ns, p.left_file, p.right_file) == (
        T0_NS + PERIOD_NS,
        T0_NS + PERIOD_NS + 7,
        "left/000001.jpg",
        "right/000001.jpg",
    )
    assert p.first_ts_ns == p.left_ts_ns


def test_a_recording_of_four_cameras_reads_back_exactly(tmp_path: Path) -> None:
    root = write_set_recording(tmp_path / "ring", RING, 3, skews_ns=(0, 1, 2, 3))
    assert (root / "frames.csv").read_text().splitlines()[0] == (
        "seq,cam1_ts_ns,cam2_ts_ns,cam3_ts_ns,cam4_ts_ns,cam1_file,cam2_file,cam3_file,cam4_file"
    )
    rec = Recording(root)
    assert rec.cameras == list(RING)
    assert [p.seq for p in rec.pairs] == [0, 1, 2]
    for p in rec.pairs:
        ts = T0_NS + p.seq * PERIOD_NS
        assert [p.ts_ns(c) for c in RING] == [ts, ts + 1, ts + 2, ts + 3]
        for c in RING:
            assert rec.read_bytes(p, c) == encode(frame_image(c, p.seq), ".jpg")
            assert p.file(c) == f"{c}/{p.seq:06d}.jpg"
    with pytest.raises(RecordingError, match=r"unknown camera 'left' \(the recording has 'cam1'"):
        rec.pairs[0].file("left")
    # A camera of the recording replays like a pair's: verbatim stamps, exact bytes.
    cam = FileCamera(file_camera_config(root, "cam3", pace="fast", timestamps="recorded"), "cam3")
    cam.open()
    frames = [cam.read(1.0) for _ in range(3)]
    assert [(f.seq, f.ts_ns) for f in frames if f] == [(p.seq, p.ts_ns("cam3")) for p in rec.pairs]
    assert all(f is not None and f.raw == (root / f"cam3/{f.seq:06d}.jpg").read_bytes() for f in frames)


def test_a_set_is_indexed_only_once_every_frame_is_on_disk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    disk = Budget()
    monkeypatch.setattr(rig.recording, "open", limited_open(tmp_path, disk), raising=False)
    frames = [encode(frame_image(c, 0), ".jpg") for c in RING]
    w = RecordingWriter(tmp_path / "ring", cameras=RING)
    w.write_set(0, [1, 2, 3, 4], frames)
    disk.remaining = sum(len(f) for f in frames[:2]) + 10  # the third frame of the next set fails
    with pytest.raises(DiskFullError, match="disk full"):
        w.write_set(1, [5, 6, 7, 8], frames)
    w.close()
    rec = Recording(tmp_path / "ring")
    assert [p.seq for p in rec.pairs] == [0]
    for c in RING:  # nothing of the failed set stays behind
        assert sorted(f.name for f in (tmp_path / "ring" / c).iterdir()) == ["000000.jpg"]


def test_bad_sets_and_indexes_are_one_line_naming_file_and_field(tmp_path: Path) -> None:
    w = RecordingWriter(tmp_path / "ring", cameras=RING)
    with pytest.raises(RecordingError, match=r"holds 4 frames \(cam1, cam2, cam3, cam4\), got 2"):
        w.write_set(0, [1, 2], [b"a", b"b"])
    w.close()
    for cameras, message in (
        (["cam1", "cam1"], "names a camera twice"),
        (["cam1", "a/b"], "camera name 'a/b' must be"),
        ([], "must be a list of names"),
    ):
        with pytest.raises(RecordingError, match=message):
            RecordingWriter(tmp_path / f"bad{len(cameras)}", cameras=cameras)
    root = write_set_recording(tmp_path / "three", RING[:3], 2)
    csv = root / "frames.csv"
    text = csv.read_text()
    csv.write_text(text + "2,1,x,3,cam1/000000.jpg,cam2/000000.jpg,cam3/000000.jpg\n")
    with pytest.raises(RecordingError) as caught:
        Recording(root)
    assert str(caught.value) == (
        f"{csv}: line 4: seq, cam1_ts_ns, cam2_ts_ns and cam3_ts_ns must be integers"
    )
    # A header of other cameras than recording.json lists.
    csv.write_text(",".join(frames_header(("left", "right"))) + "\n")
    with pytest.raises(RecordingError, match=r"line 1: header must be seq,cam1_ts_ns,cam2_ts_ns,cam3_ts_ns,"):
        Recording(root)


def test_rows_parse_and_print_alike() -> None:
    row = FrameSetRecord.of(4, {"a": 10, "b": 11, "c": 12}, {"a": "a/4.png", "b": "b/4.png", "c": "c/4.png"})
    assert row.csv_row() == "4,10,11,12,a/4.png,b/4.png,c/4.png\n"
    assert FrameSetRecord.parse(row.csv_row().strip().split(","), ["a", "b", "c"]) == row
    assert FrameSetRecord.pair(1, 2, 3, "l", "r").csv_row() == "1,2,3,l,r\n"
