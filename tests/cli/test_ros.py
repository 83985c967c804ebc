"""The ROS commands through the installed ``rig`` script (real subprocesses, real files):
``rig export mcap`` (depth equal to ``rig process``'s), ``rig process`` on ROS bags, bad bags as
one line and exit status 2 with nothing left behind, ``rig record --format mcap`` and a recording
killed with SIGKILL recovered with ``rig record --recover``."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import time
from io import BytesIO
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin

from calibration import save_rig
from rig.depth import depth_to_png_mm
from rig.ros.names import RosNames
from tests.helpers.command import RIG, clean_env, run_rig
from tests.rig.ros_fixtures import PAIRS, shot, write_jpeg_recording
from tests.rig.test_capture_bag import LEFT, RIGHT, STAMPS, write_bag

N = RosNames()
SMALL = ["--vpc-size", "160x120", "--vpc-hfov", "90"]


def run(*args: str | Path, cache: Path) -> subprocess.CompletedProcess[str]:
    """``rig ARGS`` with its LUT cache in ``cache``."""
    return run_rig(args, clean_env(RIG_CACHE_DIR=cache))


def prepared(root: Path) -> tuple[Any, list[str | Path]]:
    rec = write_jpeg_recording(root / "rec")
    save_rig(shot().rig, root / "rig.yaml")
    (root / "stereo.yaml").write_text("disparity_range: 32\n")
    return rec, ["--calibration", root / "rig.yaml", *SMALL, "--stereo", root / "stereo.yaml"]


def messages(path: Path) -> dict[str, list[Any]]:
    out: dict[str, list[Any]] = {}
    with AnyReader([path]) as reader:
        for conn, _, raw in reader.messages():
            out.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    return out


def one_error_line(res: subprocess.CompletedProcess[str], *fragments: str) -> str:
    assert res.returncode == 2, (res.returncode, res.stdout, res.stderr)
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    for f in fragments:
        assert f in lines[0], lines[0]
    return lines[0]


def png(path: Path) -> np.ndarray:
    return np.asarray(cv2.imread(str(path), cv2.IMREAD_UNCHANGED))


def test_export_mcap_depth_is_rig_process_byte_for_byte(tmp_path: Path) -> None:
    """One executor: with the temporal filter on (history across pairs), the exported 16UC1 depth
    is ``rig process``'s depth PNGs byte for byte, its range and rectified views those files'."""
    rec, opts = prepared(tmp_path)
    (tmp_path / "stereo.yaml").write_text("disparity_range: 32\ntemporal_alpha: 0.5\n")
    cache = tmp_path / "cache"
    res = run("process", rec.root, "--out", tmp_path / "out", *opts, cache=cache)
    assert res.returncode == 0, res.stderr
    export = ["export", "mcap", rec.root, "--out", tmp_path / "run.mcap", "--depth-encoding", "16UC1"]
    res = run(*export, *opts, cache=cache)
    assert res.returncode == 0, res.stderr
    assert f"exported {PAIRS} of {PAIRS} pairs" in res.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "cache",
        "out",
        "rec",
        "rig.yaml",
        "run.mcap",
        "stereo.yaml",
    ]
    msgs = messages(tmp_path / "run.mcap")
    assert len(msgs[N.depth_image]) == PAIRS
    for k, img in enumerate(msgs[N.depth_image]):
        stem = f"{k:06d}.png"
        depth = png(tmp_path / "out" / "depth" / stem)
        assert img.encoding == "16UC1" and bytes(img.data) == depth.astype("<u2").tobytes()
        rng_msg = msgs[N.range_image][k]
        rng = np.frombuffer(rng_msg.data, "<f4").reshape(rng_msg.height, rng_msg.width)
        assert np.array_equal(depth_to_png_mm(rng), png(tmp_path / "out" / "range" / stem))
        rect = msgs[N.rect_image("left")][k]
        assert np.array_equal(
            np.asarray(rect.data).reshape(rect.height, rect.width), png(tmp_path / "out" / "left" / stem)
        )
        assert bytes(msgs[N.raw_image("left", compressed=True)][k].data) == rec.jpegs[k][0]
    # The filter's history mattered: without it the later pairs' depth differs.
    (tmp_path / "stereo.yaml").write_text("disparity_range: 32\n")
    res = run("process", rec.root, "--out", tmp_path / "plain", *opts, cache=cache)
    assert res.returncode == 0, res.stderr
    stems = [f"{k:06d}.png" for k in range(PAIRS)]
    differ = [
        s
        for s in stems
        if not np.array_equal(png(tmp_path / "plain" / "depth" / s), png(tmp_path / "out" / "depth" / s))
    ]
    assert differ and stems[0] not in differ  # the first pair has no history either way


def test_process_and_export_a_ros_bag(tmp_path: Path) -> None:
    _, opts = prepared(tmp_path)
    write_bag(tmp_path / "bag", StoragePlugin.SQLITE3, left_stamps=STAMPS, right_stamps=STAMPS)
    topics = ["--left-topic", LEFT, "--right-topic", RIGHT]
    cache = tmp_path / "cache"
    res = run("process", tmp_path / "bag", "--out", tmp_path / "out", *topics, *opts, cache=cache)
    assert res.returncode == 0, res.stderr
    assert f"processed {len(STAMPS)} of {len(STAMPS)} pairs" in res.stdout
    assert len(list((tmp_path / "out" / "depth").iterdir())) == len(STAMPS)
    res = run("export", "mcap", tmp_path / "bag", "--out", tmp_path / "b.mcap", *topics, *opts, cache=cache)
    assert res.returncode == 0, res.stderr
    msgs = messages(tmp_path / "b.mcap")
    # Raw mono8 frames of the bag become raw images; its JPEG frames stay compressed.
    assert len(msgs[N.raw_image("left", compressed=False)]) == len(STAMPS)
    assert len(msgs[N.raw_image("right", compressed=True)]) == len(STAMPS)


def test_bad_bags_are_one_line_and_leave_nothing(tmp_path: Path) -> None:
    _, opts = prepared(tmp_path)
    cache = tmp_path / "cache"
    write_bag(tmp_path / "bag", StoragePlugin.MCAP, left_stamps=STAMPS, right_stamps=STAMPS)
    mcap = next((tmp_path / "bag").glob("*.mcap"))
    write_bag(
        tmp_path / "off",
        StoragePlugin.MCAP,
        left_stamps=STAMPS,
        right_stamps=[t + 400_000_000 for t in STAMPS],
    )
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    cases = [
        (mcap, ["--left-topic", "/cam9/image_raw", "--right-topic", RIGHT], ["no topic '/cam9/image_raw'"]),
        (tmp_path / "off", ["--left-topic", LEFT, "--right-topic", RIGHT], ["are not synchronised"]),
        (cut, ["--left-topic", LEFT, "--right-topic", RIGHT], ["cut.mcap: truncated or corrupt bag"]),
        (mcap, [], ["a ROS bag: name its two image topics"]),
    ]
    for source, topics, fragments in cases:
        res = run("process", source, "--out", tmp_path / "out", *topics, *opts, cache=cache)
        one_error_line(res, *fragments)
        assert not (tmp_path / "out").exists()
    # The export reads its input through the same function: one case shows it leaves no file.
    source, topics, fragments = cases[1]
    one_error_line(
        run("export", "mcap", source, "--out", tmp_path / "x.mcap", *topics, *opts, cache=cache), *fragments
    )
    assert not list(tmp_path.glob("x.mcap*"))


def test_record_mcap_from_a_replay(tmp_path: Path) -> None:
    rec = write_jpeg_recording(tmp_path / "rec")
    res = run(
        "record", "--replay", rec.root, "--format", "mcap", "--out", tmp_path / "r.mcap", cache=tmp_path / "c"
    )
    assert res.returncode == 0, res.stderr
    assert f"recorded {PAIRS} pairs" in res.stdout
    msgs = messages(tmp_path / "r.mcap")
    assert [bytes(m.data) for m in msgs[N.raw_image("left", compressed=True)]] == [j[0] for j in rec.jpegs]
    assert [bytes(m.data) for m in msgs[N.raw_image("right", compressed=True)]] == [j[1] for j in rec.jpegs]
    again = run(
        "record", "--replay", rec.root, "--format", "mcap", "--out", tmp_path / "r.mcap", cache=tmp_path / "c"
    )
    one_error_line(again, "r.mcap: already exists")


def complete_chunks(path: Path) -> int:
    """How many whole chunks the MCAP file being written at ``path`` holds so far (0 if none yet)."""
    count = 0
    if not path.exists():
        return count
    try:
        for record in StreamReader(BytesIO(path.read_bytes()), emit_chunks=True, validate_crcs=True).records:
            count += isinstance(record, Chunk)
    except (McapError, ValueError, EOFError, struct.error):
        pass  # where the writer is at
    return count


@pytest.mark.slow
def test_a_killed_mcap_recording_is_recovered(tmp_path: Path) -> None:
    """SIGKILL in the middle of a paced recording: no file under the final name, the partial
    file recovers to a run of the source's frames, byte-exact and in order."""
    rec = write_jpeg_recording(tmp_path / "rec", pairs=6)
    camera = f"{{kind: file, recording: {rec.root}, pace: 20, loop: true, timestamps: live}}"
    (tmp_path / "cams.yaml").write_text(f"cameras:\n  left: {camera}\n  right: {camera}\n")
    out = tmp_path / "k.mcap"
    env = {**os.environ, "RIG_CACHE_DIR": str(tmp_path / "c")}
    proc = subprocess.Popen(
        [RIG, "record", "--config", str(tmp_path / "cams.yaml"), "--format", "mcap", "--out", str(out)],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    partial = tmp_path / "k.mcap.partial"
    deadline = time.monotonic() + 60
    while complete_chunks(partial) < 2:  # a few chunks on disk (its size alone can be mid-chunk)
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read() if proc.stderr else ""
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    assert not out.exists() and partial.exists()
    res = run("record", "--recover", partial, cache=tmp_path / "c")
    assert res.returncode == 0, res.stderr
    assert "(cut short)" in res.stdout and out.exists() and not partial.exists()
    msgs = messages(out)
    lefts = [bytes(m.data) for m in msgs[N.raw_image("left", compressed=True)]]
    stamps = [
        m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        for m in msgs[N.raw_image("left", compressed=True)]
    ]
    source = [j[0] for j in rec.jpegs]
    assert len(lefts) >= 5 and stamps == sorted(stamps)
    # Each frame is the source's frame due at its timestamp (live timestamps are due times, 50 ms
    # apart): byte-exact and in loop order. A camera thread starved on a loaded machine skips the
    # frames due while it could not run, never delivers one out of turn.
    at = [source.index(frame) for frame in lefts]
    for k in range(1, len(lefts)):
        due = round((stamps[k] - stamps[k - 1]) / 50e6)
        assert due >= 1 and at[k] == (at[k - 1] + due) % len(source), (k, at, stamps)
