"""Recording to MCAP: frames byte-exact, atomic file, and what a killed recorder leaves (every
chunk written so far) recovered."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from rig.errors import RecordingError
from rig.ros.mcap_export import McapRecordingWriter
from rig.ros.mcap_writer import recover_mcap

TOPICS = ("/rig/left/image_raw/compressed", "/rig/right/image_raw/compressed")


def jpeg(k: int, cam: int) -> bytes:
    # Distinct bytes per frame (the writer does not decode JPEG).
    return b"\xff\xd8\xff\xe0" + bytes([k, cam]) * 500 + b"\xff\xd9"


def read(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    out: dict[str, list[tuple[int, bytes]]] = {}
    with AnyReader([path]) as reader:
        for conn, t, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            out.setdefault(conn.topic, []).append((t, bytes(msg.data)))
    return out


def test_recording_is_byte_exact_and_appears_only_when_complete(tmp_path: Path) -> None:
    out = tmp_path / "run.mcap"
    w = McapRecordingWriter(out)
    for k in range(5):
        w.write_pair(k, 1000 + k, 1001 + k, jpeg(k, 0), jpeg(k, 1))
    assert not out.exists() and (tmp_path / "run.mcap.partial").exists()
    w.close()
    assert out.exists() and not (tmp_path / "run.mcap.partial").exists()
    got = read(out)
    assert got[TOPICS[0]] == [(1000 + k, jpeg(k, 0)) for k in range(5)]
    assert got[TOPICS[1]] == [(1001 + k, jpeg(k, 1)) for k in range(5)]
    with pytest.raises(RecordingError, match="already exists"):
        McapRecordingWriter(out)


def test_png_and_decoded_frames_become_raw_images(tmp_path: Path) -> None:
    import cv2

    img = np.arange(48 * 64, dtype=np.uint8).reshape(48, 64)
    png = cv2.imencode(".png", img)[1].tobytes()
    with McapRecordingWriter(tmp_path / "p.mcap") as w:
        w.write_pair(0, 5, 6, png, png, ext=".png")
        w.write_images(1, 7, 8, np.dstack([img, img, img]), img)
    with AnyReader([tmp_path / "p.mcap"]) as reader:
        msgs = [(c.topic, reader.deserialize(raw, c.msgtype)) for c, _, raw in reader.messages()]
    left = [m for t, m in msgs if t == "/rig/left/image_raw"]
    assert [m.encoding for m in left] == ["mono8", "bgr8"]
    assert np.array_equal(np.asarray(left[0].data).reshape(48, 64), img)


@pytest.mark.parametrize("chunk_size", [1, 1 << 20])
def test_a_killed_recording_loses_at_most_the_chunk_in_progress(tmp_path: Path, chunk_size: int) -> None:
    """The partial file as a SIGKILL would leave it after each pair (everything the writer has
    handed to the kernel; the chunk in progress is in the process's memory) recovers to at
    least every pair of the closed chunks: here every pair, as each pair closes its chunk
    (chunk_size 1) or the flush interval is 0."""
    out = tmp_path / "run.mcap"
    w = McapRecordingWriter(out, chunk_size=chunk_size, flush_interval_s=0.0 if chunk_size > 1 else 3600.0)
    for k in range(4):
        w.write_pair(k, 1000 + k, 1001 + k, jpeg(k, 0), jpeg(k, 1))
        snapshot = tmp_path / f"kill{k}.mcap.partial"
        shutil.copyfile(tmp_path / "run.mcap.partial", snapshot)
        result = recover_mcap(snapshot)
        assert result.path == tmp_path / f"kill{k}.mcap" and not result.complete and not snapshot.exists()
        got = read(result.path)
        assert got[TOPICS[0]] == [(1000 + j, jpeg(j, 0)) for j in range(k + 1)]
        assert got[TOPICS[1]] == [(1001 + j, jpeg(j, 1)) for j in range(k + 1)]
    w.abandon()  # what a crash leaves: the partial file, no final one
    assert not out.exists()
    with pytest.raises(RecordingError, match=r"run\.mcap\.partial: exists .*`rig record --recover "):
        McapRecordingWriter(out)
    assert recover_mcap(tmp_path / "run.mcap.partial").messages == 8


def test_recover_refuses_what_holds_nothing(tmp_path: Path) -> None:
    empty = tmp_path / "x.mcap.partial"
    empty.write_bytes(b"\x89MCAP0\r\n")
    with pytest.raises(RecordingError, match="holds no complete MCAP chunk"):
        recover_mcap(empty)
    assert empty.exists() and not (tmp_path / "x.mcap").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["x.mcap.partial"]  # no temporary left either
