"""RecordingWriter under a full disk (ENOSPC injected into its writes) and bad sequence numbers:
what was indexed stays readable and nothing half-written is left behind."""

from __future__ import annotations

from pathlib import Path

import pytest

import rig.recording
from rig.errors import DiskFullError, RecordingError
from rig.recording import Recording, RecordingWriter
from tests.helpers.recordings import encode, frame_image
from tests.reliability.fake_disk import Budget, limited_open


@pytest.fixture
def disk(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Budget:
    """Every file the writer opens under ``tmp_path`` draws on one budget (unlimited until set)."""
    d = Budget()
    monkeypatch.setattr(rig.recording, "open", limited_open(tmp_path, d), raising=False)
    return d


FRAMES = {
    k: (encode(frame_image("left", k), ".jpg"), encode(frame_image("right", k), ".jpg")) for k in range(6)
}


def write(w: RecordingWriter, k: int) -> None:
    w.write_pair(k, 1000 + k, 1001 + k, *FRAMES[k])


def assert_intact(root: Path, n: int) -> None:
    rec = Recording(root)
    assert [p.seq for p in rec.pairs] == list(range(n)) and not rec.truncated_tail
    for p in rec.pairs:
        assert (
            rec.read_bytes(p, "left") == FRAMES[p.seq][0] and rec.read_bytes(p, "right") == FRAMES[p.seq][1]
        )
        rec.read_image(p, "left")
    # Nothing unindexed stays behind.
    assert sorted(f.name for f in (root / "left").iterdir()) == [f"{k:06d}.jpg" for k in range(n)]
    assert sorted(f.name for f in (root / "right").iterdir()) == [f"{k:06d}.jpg" for k in range(n)]


def test_disk_full_while_writing_a_frame(tmp_path: Path, disk: Budget) -> None:
    w = RecordingWriter(tmp_path / "rec")
    for k in range(3):
        write(w, k)
    disk.remaining = len(FRAMES[3][0]) + 100  # the left frame fits, the right one does not
    with pytest.raises(DiskFullError, match="disk full"):
        write(w, 3)
    w.close()
    assert_intact(tmp_path / "rec", 3)


def test_disk_full_in_the_middle_of_an_index_row(tmp_path: Path, disk: Budget) -> None:
    w = RecordingWriter(tmp_path / "rec")
    for k in range(2):
        write(w, k)
    disk.remaining = len(FRAMES[2][0]) + len(FRAMES[2][1]) + 9  # frames fit, 9 bytes of the row
    with pytest.raises(DiskFullError):
        write(w, 2)
    w.close()
    assert (tmp_path / "rec/frames.csv").read_text().endswith("\n")  # the partial row was cut off
    assert_intact(tmp_path / "rec", 2)


def test_other_write_errors_are_recording_errors(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    w = RecordingWriter(tmp_path / "rec")
    write(w, 0)
    (tmp_path / "rec/left").rename(tmp_path / "rec/gone")
    with pytest.raises(RecordingError, match="cannot write recording") as err:
        write(w, 1)
    assert not isinstance(err.value, DiskFullError)


def test_duplicate_or_negative_seq_is_refused(tmp_path: Path) -> None:
    with RecordingWriter(tmp_path / "rec") as w:
        write(w, 0)
        with pytest.raises(RecordingError, match="seq 0 already written"):
            write(w, 0)
        with pytest.raises(RecordingError, match="negative"):
            w.write_pair(-1, 0, 0, b"a", b"b")
    assert_intact(tmp_path / "rec", 1)


def test_a_row_cut_by_a_crash_is_skipped(tmp_path: Path) -> None:
    with RecordingWriter(tmp_path / "rec") as w:
        for k in range(2):
            write(w, k)
    with open(tmp_path / "rec/frames.csv", "a") as f:
        f.write("2,1002,10")  # what kill -9 in the middle of a row would leave
    rec = Recording(tmp_path / "rec")
    assert len(rec) == 2 and rec.truncated_tail
