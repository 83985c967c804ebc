"""RecordingManager on its own: name validation, byte-exact writes, bounded queue with counted
drops, listing, and the stop note in recording.json."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import rig.recording
from calibration import load_rig
from rig.capture.frame import Frame, FramePair
from rig.errors import DiskFullError
from rig.recording import Recording
from rig.sim import get_preset
from service.errors import RecordingConflict, RecordingNameError, RecordingNotFound, RecordingStorageError
from service.recordings import RecordingManager, _Active, recording_path, validate_name
from tests.helpers.recordings import encode
from tests.reliability.fake_disk import limited_open


def jpeg_pair(seq: int) -> FramePair:
    rng = np.random.default_rng(seq)
    frames = []
    for cam in ("left", "right"):
        raw = encode(rng.integers(0, 256, (24, 32, 3), dtype=np.uint8), ".jpg")
        frames.append(Frame(cam, seq, 1_000 + seq * 33_000_000, "jpeg", 0, raw=raw))
    return FramePair(frames[0], frames[1])


@pytest.mark.parametrize(
    "name", ["../x", "/abs", "", "a" * 65, "a..b", ".hidden", "a/b", "a\\b", "-lead", "sp ace", "..", "x\x00"]
)
def test_bad_names_rejected(tmp_path: Path, name: str) -> None:
    with pytest.raises(RecordingNameError):
        validate_name(name)
    with pytest.raises(RecordingNameError):
        RecordingManager(tmp_path).start(name)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("name", ["run1", "A.b-c_d", "2024-05-01T10.00", "x" * 64])
def test_good_names_stay_inside(tmp_path: Path, name: str) -> None:
    assert recording_path(tmp_path, name) == tmp_path.resolve() / name


def test_symlinked_name_cannot_escape(tmp_path: Path) -> None:
    root = tmp_path / "recs"
    root.mkdir()
    (root / "link").symlink_to(tmp_path)
    with pytest.raises(RecordingNameError, match="outside"):
        recording_path(root, "link")


def test_record_byte_exact_then_list(tmp_path: Path) -> None:
    rig = get_preset("paper-sim").rig
    mgr = RecordingManager(tmp_path / "recs", queue_size=64, rig=rig)
    started = mgr.start("run1", {"note": "test"})
    assert started.active and started.pairs == 0
    pairs = [jpeg_pair(s) for s in range(5)]
    for p in pairs:
        mgr.offer(p)
    with pytest.raises(RecordingConflict, match="running"):
        mgr.start("run2")
    with pytest.raises(RecordingNotFound):
        mgr.stop("other")
    done = mgr.stop("run1")
    assert not done.active and done.pairs == 5 and done.dropped == 0 and done.stopped_at is not None
    rec = Recording(tmp_path / "recs" / "run1")
    assert [p.seq for p in rec.pairs] == [0, 1, 2, 3, 4]
    for p, src in zip(rec.pairs, pairs, strict=True):
        assert rec.read_bytes(p, "left") == src.left.raw and rec.read_bytes(p, "right") == src.right.raw
        assert (p.left_ts_ns, p.right_ts_ns) == (src.left.ts_ns, src.right.ts_ns)
    assert rec.meta["note"] == "test" and rec.meta["pairs"] == 5 and rec.meta["stopped_at"] == done.stopped_at
    assert load_rig(rec.calibration_path or "").baseline() == pytest.approx(rig.baseline())
    listing = mgr.list()
    assert [r.name for r in listing] == ["run1"]
    assert listing[0].pairs == 5 and listing[0].bytes > sum(len(p.left.raw or b"") for p in pairs)
    with pytest.raises(RecordingConflict, match="already exists"):
        mgr.start("run1")


def test_full_queue_drops_and_counts(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    gate = threading.Event()
    original = _Active._write

    def slow_write(self: _Active, pair: FramePair) -> None:
        gate.wait()
        original(self, pair)

    monkeypatch.setattr(_Active, "_write", slow_write)
    mgr = RecordingManager(tmp_path, queue_size=2)
    mgr.start("busy")
    for s in range(10):
        mgr.offer(jpeg_pair(s))  # never blocks, even with the writer stuck
    active = mgr.active
    assert active is not None
    # The writer holds at most one pair, the queue two: the other seven are dropped and counted.
    assert 7 <= active.dropped <= 8
    gate.set()
    done = mgr.stop("busy")
    assert done.pairs + done.dropped == 10
    assert json.loads((tmp_path / "busy" / "recording.json").read_text())["dropped"] == done.dropped
    assert mgr.list()[0].dropped == done.dropped


def test_seq_going_back_stops_writing_with_a_reason(tmp_path: Path) -> None:
    mgr = RecordingManager(tmp_path)
    mgr.start("loop")
    for s in (3, 4, 1, 5):
        mgr.offer(jpeg_pair(s))
    done = mgr.stop("loop")
    assert done.pairs == 2
    assert done.error is not None and "went from 4 back to 1" in done.error


def test_close_finishes_a_running_recording(tmp_path: Path) -> None:
    mgr = RecordingManager(tmp_path)
    mgr.start("r")
    mgr.offer(jpeg_pair(0))
    mgr.close()
    assert mgr.active is None
    assert len(Recording(tmp_path / "r").pairs) == 1
    mgr.offer(jpeg_pair(1))  # no recording: ignored
    assert mgr.list()[0].pairs == 1


def _files_bytes(root: Path) -> int:
    return sum(f.stat().st_size for f in root.rglob("*") if f.is_file())


def test_bytes_are_counted_as_the_writer_writes(tmp_path: Path) -> None:
    mgr = RecordingManager(tmp_path, rig=get_preset("paper-sim").rig)
    mgr.start("counted")
    for s in range(4):
        mgr.offer(jpeg_pair(s))
    wait_until = time.monotonic() + 10
    while (mgr.active is None or mgr.active.pairs < 4) and time.monotonic() < wait_until:
        time.sleep(0.01)
    active = mgr.active
    assert active is not None and active.pairs == 4
    assert active.bytes == _files_bytes(tmp_path / "counted")
    done = mgr.stop("counted")
    on_disk = _files_bytes(tmp_path / "counted")
    assert done.bytes == on_disk and mgr.list()[0].bytes == on_disk
    assert json.loads((tmp_path / "counted" / "recording.json").read_text())["pairs"] == 4


def test_the_status_of_a_running_recording_does_not_walk_its_files(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What /health asks of the running recording costs the same with 3 000 files as with none."""
    mgr = RecordingManager(tmp_path)
    mgr.start("long")
    calls = {"n": 0}
    for name in ("stat", "lstat", "scandir", "listdir", "walk"):
        real = getattr(os, name)

        def counting(*args: Any, _real: Any = real, **kw: Any) -> Any:
            calls["n"] += 1
            return _real(*args, **kw)

        monkeypatch.setattr(os, name, counting)
    costs = []
    for files in (0, 3000):
        extra = tmp_path / "long" / f"extra{files}"
        extra.mkdir()
        for k in range(files):
            (extra / f"{k:06d}.jpg").touch()
        calls["n"] = 0
        assert mgr.active is not None
        costs.append(calls["n"])
    assert costs[1] == costs[0] <= 2, costs
    mgr.stop("long")


def test_a_recordings_dir_that_cannot_hold_recordings_says_so(tmp_path: Path) -> None:
    a_file = tmp_path / "recordings"
    a_file.write_text("not a directory")
    for root in (a_file, a_file / "below"):
        mgr = RecordingManager(root)
        with pytest.raises(RecordingStorageError, match=r"server.recordings_dir .*not a directory"):
            mgr.start("run")
        assert mgr.active is None and mgr.list() == []
    assert a_file.read_text() == "not a directory"


def test_a_recording_that_cannot_start_leaves_nothing_and_its_name_free(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    root = tmp_path / "recs"
    mgr = RecordingManager(root)
    with monkeypatch.context() as patch:  # a full disk: the writer's first file fails
        patch.setattr(rig.recording, "open", limited_open(root, 0), raising=False)
        with pytest.raises(DiskFullError):
            mgr.start("first")
    assert mgr.active is None and not (root / "first").exists()
    mgr.start("first")
    mgr.offer(jpeg_pair(0))
    assert mgr.stop("first").pairs == 1
