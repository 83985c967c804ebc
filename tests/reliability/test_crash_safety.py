"""Crash safety of recordings.

- ``kill -9`` of ``rig record --replay`` (the real console script, replaying a JPEG recording
  as fast as it can write) at seeded random moments: the recording opens, its index is exactly
  a prefix of the source (same seq, timestamps, file names), every indexed frame decodes and is
  byte-equal to the source frame, nothing acknowledged before the kill is missing, and at most
  one pair (the one in flight) left files behind without an index row.
- A full disk, for ``rig record`` and for the service's recorder, on a real small tmpfs (the
  tests skip, saying why, where none can be mounted: root with CAP_SYS_ADMIN is needed). The
  recorder stops with one clear line (exit 2) or a recording error in the API, and what was
  written stays readable.
- The same recorder code path on any machine, with ENOSPC injected into the recorder's writes
  (``fake_disk``): separate tests, named as such.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import pytest

import rig.recording
from rig.recording import Recording
from tests.helpers.command import RIG, assert_one_line_error, clean_env, run_rig
from tests.helpers.disks import SmallDisk, tmpfs_disk
from tests.helpers.recordings import write_recording
from tests.helpers.service import TOKEN, StartApp
from tests.helpers.waiting import wait_for
from tests.reliability.fake_disk import limited_open

pytestmark = [pytest.mark.timeout(300)]

REPO = Path(__file__).resolve().parents[2]
SOURCE_PAIRS = 800
KILLS = 6
SEED = 20240909


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """800 pairs of distinct 320x240 JPEG frames (seq k at t0 + k/30 s) with a calibration.yaml."""
    return write_recording(
        tmp_path_factory.mktemp("crash") / "src",
        SOURCE_PAIRS,
        width=320,
        height=240,
        calibration="cameras: {}\n",
    )


def indexed_rows(index: Path) -> int:
    try:
        return max(0, index.read_bytes().count(b"\n") - 1)
    except FileNotFoundError:
        return 0


def rows_reached(proc: subprocess.Popen[bytes], index: Path, target: int) -> Callable[[], int]:
    """For ``wait_for``: the rows in ``index`` once there are ``target`` (0 before), while the
    recorder is still running."""

    def reached() -> int:
        assert proc.poll() is None, f"rig record ended before the kill: {proc.stderr}"
        n = indexed_rows(index)
        return n if n >= target else 0

    return reached


def check_recording(src: Recording, out: Path, *, at_least: int = 0) -> tuple[Recording, set[str]]:
    """The recording at ``out`` opens and is a byte-exact prefix of ``src``; returns it and the
    stems of frame files on disk that no index row names."""
    rec = Recording(out)
    n = len(rec)
    assert n >= at_least, f"{n} pairs indexed, {at_least} were acknowledged before"
    assert rec.pairs == src.pairs[:n]  # same seq, timestamps and file names, in order
    for pair in rec.pairs:
        for cam in ("left", "right"):
            data = rec.read_bytes(pair, cam)
            assert data == src.read_bytes(pair, cam), (pair.seq, cam)
            img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
            assert img is not None and img.shape == (240, 320, 3)
    orphans: set[str] = set()
    for cam in ("left", "right"):
        indexed = {Path(p.file(cam)).name for p in rec.pairs}
        on_disk = {f.name for f in (out / cam).iterdir()}
        assert indexed <= on_disk
        orphans |= {Path(name).stem for name in on_disk - indexed}
    return rec, orphans


@pytest.mark.slow
def test_kill_9_at_random_moments_loses_at_most_the_pair_in_flight(source: Path, tmp_path: Path) -> None:
    rng = random.Random(SEED)
    src = Recording(source)
    report = []
    for i in range(KILLS):
        target = rng.randint(1, SOURCE_PAIRS * 2 // 3)
        extra_s = rng.uniform(0.0, 0.004)  # lands the kill anywhere in a pair's write cycle
        out = tmp_path / f"out{i}"
        proc = subprocess.Popen(
            [str(RIG), "record", "--replay", str(source), "--out", str(out)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            env=clean_env(tmp_path),
        )
        try:
            acked = wait_for(rows_reached(proc, out / "frames.csv", target), 120, f"{target} rows", 0.0005)
            time.sleep(extra_s)
        finally:
            proc.send_signal(signal.SIGKILL)
            _, stderr = proc.communicate(timeout=30)
        assert proc.returncode == -signal.SIGKILL, (proc.returncode, stderr)
        rec, orphans = check_recording(src, out, at_least=acked)
        n = len(rec)
        # At most one pair lost: the one being written when the process died.
        assert len(orphans) + rec.truncated_tail <= 1, (orphans, rec.truncated_tail)
        if orphans:
            in_flight = src.pairs[n]
            assert orphans == {f"{in_flight.seq:06d}"}
            for cam in ("left", "right"):
                partial = out / in_flight.file(cam)
                if partial.exists():  # a prefix of the real frame, nothing foreign
                    assert src.read_bytes(in_flight, cam).startswith(partial.read_bytes())
        report.append(f"kill after {acked} acked: {n} indexed, {len(orphans)} in flight")
    print("\n" + "; ".join(report))


# ----- full disk ---------------------------------------------------------------------------------
@contextmanager
def injected_disk(where: Path, size: int) -> Iterator[SmallDisk]:
    """A byte budget of ``size`` on rig.recording's writes under ``where`` (``fake_disk``), for a
    subprocess through its environment and for this process through ``rig.recording.open``."""
    where.mkdir(parents=True)
    hook = Path(__file__).with_name("enospc_hook")
    env = {
        "PYTHONPATH": os.pathsep.join([str(hook), str(REPO)]),
        "FAKE_DISK_ROOT": str(where),
        "FAKE_DISK_BUDGET_BYTES": str(size),
    }
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(rig.recording, "open", limited_open(where, size), raising=False)
        yield SmallDisk(where, size, env)


DISKS = {"tmpfs": tmpfs_disk, "injected-ENOSPC": injected_disk}


def check_rig_record_on_a_full_disk(source: Path, tmp_path: Path, disk: SmallDisk) -> str:
    """``rig record --replay`` onto ``disk`` stops with one line and keeps what was written."""
    src = Recording(source)
    frame_bytes = sum(len(src.read_bytes(p, c)) for p in src.pairs[:10] for c in ("left", "right")) // 20
    out = disk.root / "rec"
    res = run_rig(["record", "--replay", str(source), "--out", str(out)], env=clean_env(tmp_path, **disk.env))
    line = assert_one_line_error(res, f"{out}: disk full", "stays readable")
    rec, orphans = check_recording(src, out)
    n = len(rec)
    assert f"({n} pairs written" in line
    # Most of the room went into frames (4 KiB pages and the header files take the rest).
    assert 0.5 * disk.size / (2 * frame_bytes) <= n < SOURCE_PAIRS
    assert not orphans and not rec.truncated_tail  # the partial pair was removed
    assert (out / "frames.csv").read_bytes().endswith(b"\n")
    return f"{n} pairs kept; {line}"


@pytest.mark.parametrize("kind", DISKS)
def test_full_disk_stops_rig_record_with_one_line_and_keeps_what_was_written(
    source: Path, tmp_path: Path, kind: str
) -> None:
    with DISKS[kind](tmp_path / "disk", 400 * 1024) as disk:
        print(f"\nrig record, full disk ({kind}): {check_rig_record_on_a_full_disk(source, tmp_path, disk)}")


@pytest.mark.parametrize("kind", DISKS)
def test_full_disk_under_the_running_service(
    start_app: StartApp, jpeg_recording: Path, tmp_path: Path, kind: str
) -> None:
    src = Recording(jpeg_recording)
    with DISKS[kind](tmp_path / "disk", 2 * 1024 * 1024) as disk:
        live = start_app(recordings_dir=str(disk.root))
        with live.rig_client(TOKEN) as client:
            client.start_recording("fills-the-disk")
            wait_for(lambda: client.recordings()[0].error is not None, 60, "the disk to fill")
            failing = client.recordings()[0]
            assert failing.active and "disk full" in (failing.error or "")
            # The service carries on (depth keeps coming) but says the recording has stopped.
            seq = client.depth().seq
            wait_for(lambda: client.depth().seq > seq, 10, "depth after the disk filled")
            health = client.health()
            assert health.status == "degraded"
            assert any("fills-the-disk" in r and "disk full" in r for r in health.reasons)
            done = client.stop_recording("fills-the-disk")
            assert not done.active and "disk full" in (done.error or "")
            wait_for(lambda: client.health().status == "ok", 10, "health ok once the recording is stopped")
        rec = Recording(done.path)
        assert len(rec) == done.pairs >= 1 and not rec.truncated_tail
        for pair in rec.pairs:
            original = src.pairs[pair.seq % len(src.pairs)]  # live seq = recorded seq + loops * 3
            for cam in ("left", "right"):
                assert rec.read_bytes(pair, cam) == src.read_bytes(original, cam)
        on_disk = {f.name for f in (Path(done.path) / "left").iterdir()}
        assert on_disk == {Path(p.left_file).name for p in rec.pairs}
        print(f"\nservice recording, full disk ({kind}): {len(rec)} pairs kept")
