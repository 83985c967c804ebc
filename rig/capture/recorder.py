"""Capture → recording directory or MCAP file (``rig record``): every pair (every set of a rig
of N cameras), in order, byte-exact.

Sets are taken oldest-first from a :class:`~rig.capture.capture.RigCapture` and written
with a :class:`~rig.recording.PairWriter`: :class:`~rig.recording.RecordingWriter` (frame files
first, then the ``frames.csv`` row, so a killed recorder loses at most the pair in flight), or
an MCAP writer (a killed recorder loses at most the chunk in progress). MJPEG/PNG frames are stored as
delivered; frames that arrive decoded (YUYV) are stored as lossless PNG. A replayed recording
(``replay_capture_config``) reproduces its source byte for byte: same ``seq``, timestamps,
file names and bytes.
"""

from __future__ import annotations

import itertools
import shutil
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from rig.capture.capture import RigCapture
from rig.capture.config import CaptureConfig, FileCameraConfig, PairingConfig, SupervisorConfig
from rig.capture.frame import FrameSet
from rig.capture.health import CaptureHealth
from rig.errors import CameraUnavailable, RecordingError
from rig.recording import PairWriter, Recording

__all__ = ["RecordResult", "Recorder", "copy_calibration", "replay_capture_config", "store_set"]

# Replays wait on the writer under backpressure, which must not look like a stalled camera.
_REPLAY_SUPERVISOR = SupervisorConfig(
    watchdog_s=3600.0, reconnect_after_s=7200.0, read_timeout_s=0.25, decode=False, usb_reset_after=0
)


def replay_capture_config(recording: str | Path) -> tuple[CaptureConfig, Recording]:
    """Capture config that replays ``recording`` verbatim, as fast as the writer takes it.

    The skew gate admits every recorded set (its largest spread of capture times), and at least
    half a frame period, so the sets come out exactly as they were indexed. A recording of N
    cameras replays as a rig of its N cameras.
    """
    rec = Recording(recording)
    if not rec.pairs:
        raise RecordingError(f"{rec.root / 'frames.csv'}: recording holds no frames")
    skews = [max(p.stamps) - min(p.stamps) for p in rec.pairs]
    steps = [b.first_ts_ns - a.first_ts_ns for a, b in itertools.pairwise(rec.pairs)]
    positive = [d for d in steps if d > 0]
    half_period = statistics.median(positive) / 2 if positive else 16_666_667
    gate_ns = max(half_period, max(skews) + 1)
    cams = {
        name: FileCameraConfig(
            recording=rec.root, camera=name, pace="fast", loop=False, timestamps="recorded", faults=()
        )
        for name in rec.cameras
    }
    two = rec.cameras == ["left", "right"]
    cfg = CaptureConfig(
        left=cams["left"] if two else None,
        right=cams["right"] if two else None,
        rig=None if two else cams,
        pairing=PairingConfig(skew_gate_ms=gate_ns / 1e6, backpressure=True),
        supervisor=_REPLAY_SUPERVISOR,
    )
    return cfg, rec


@dataclass(frozen=True)
class RecordResult:
    pairs_written: int
    stopped_by: str
    health: CaptureHealth


class Recorder:
    """Writes the pairs of a running capture into a recording directory.

    The directory is created by ``open_writer`` when the first pair arrives (or by
    :meth:`finish`), so a recorder that fails to start leaves nothing behind.
    """

    def __init__(self, capture: RigCapture, open_writer: Callable[[], PairWriter]) -> None:
        self.capture = capture
        self._open_writer = open_writer
        self.writer: PairWriter | None = None
        self.written = 0
        self._last_seq: int | None = None

    def _writer(self) -> PairWriter:
        if self.writer is None:
            self.writer = self._open_writer()
        return self.writer

    def write(self, pair: FrameSet) -> None:
        writer = self._writer()
        seq = pair.seq
        if self._last_seq is not None and seq <= self._last_seq:
            raise RecordingError(
                f"{writer.root}: {pair.cameras[0]} camera seq went from {self._last_seq} back to {seq} "
                "(a looping replay with recorded timestamps cannot be recorded; use timestamps: live)"
            )
        store_set(writer, pair)
        self._last_seq = seq
        self.written += 1

    def complete(self) -> None:
        """Close the recording; a run that ended normally without pairs still leaves an (empty)
        valid recording."""
        self._writer().close()

    def close(self) -> None:
        """Close without creating anything (error paths)."""
        if self.writer is not None:
            self.writer.close()

    def run(
        self,
        *,
        max_pairs: int | None = None,
        max_seconds: float | None = None,
        should_stop: Callable[[], bool] = lambda: False,
        on_pair: Callable[[int], None] | None = None,
        startup_timeout_s: float | None = None,
    ) -> RecordResult:
        """Record until a limit, the end of a replay, or ``should_stop()``; returns what happened.

        RecordingError/DiskFullError propagate (everything written before stays indexed). With
        ``startup_timeout_s``, a camera still unavailable when no pair has come by then raises
        CameraUnavailable with its reason (a recorder should not wait forever for a typo).
        """
        start = time.monotonic()
        stopped_by = "signal"
        while not should_stop():
            if (
                startup_timeout_s is not None
                and not self.written
                and time.monotonic() - start > startup_timeout_s
            ):
                self._check_cameras()
            if max_pairs is not None and self.written >= max_pairs:
                stopped_by = "frames"
                break
            if max_seconds is not None and time.monotonic() - start >= max_seconds:
                stopped_by = "seconds"
                break
            pair = self.capture.next_set(0.1, newest=False)
            if pair is None:
                if self.capture.exhausted:
                    stopped_by = "end of recording"
                    break
                continue
            self.write(pair)
            if on_pair is not None:
                on_pair(self.written)
        return RecordResult(self.written, stopped_by, self.capture.health())

    def _check_cameras(self) -> None:
        down = [c for c in self.capture.health().cameras.values() if c.state in ("unavailable", "starting")]
        if down:
            raise CameraUnavailable(
                "; ".join(c.reason or f"camera {c.name}: no frame yet" for c in down) + " (no pair recorded)"
            )


def store_set(writer: PairWriter, frames: FrameSet) -> None:
    """One set into ``writer``: the frames' bytes as the cameras delivered them when every one
    has them in one format (MJPEG, PNG), else the decoded images (stored losslessly)."""
    stamps = [f.ts_ns for f in frames.frames]
    raws = [f.raw for f in frames.frames]
    extensions = {f.extension for f in frames.frames}
    if all(raw is not None for raw in raws) and len(extensions) == 1:
        encoded = [raw for raw in raws if raw is not None]
        writer.write_set(frames.seq, stamps, encoded, ext=frames.frames[0].extension or ".jpg")
    else:
        writer.write_set_images(frames.seq, stamps, [f.image for f in frames.frames])


def copy_calibration(source: Recording, out: Path) -> bool:
    """Copy ``calibration.yaml`` of a replayed recording along; True if there was one."""
    src = source.calibration_path
    if src is None:
        return False
    try:
        shutil.copyfile(src, out / "calibration.yaml")
    except OSError as err:
        raise RecordingError(f"{out / 'calibration.yaml'}: cannot copy calibration ({err.strerror})") from err
    return True
