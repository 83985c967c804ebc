"""MCAP files for ROS 2 and Foxglove: a recording's depth exported (``rig export mcap``), and new
recordings written straight to MCAP (``rig record --format mcap``).

:func:`export_mcap` runs depth over every pair of a recording (a directory or a bag) the way
``rig process`` does, on the same executor (:func:`rig.recording_depth.process_pairs`: the same
depth, bit for bit, the same failures, the same stage times), with an MCAP file as the sink
(:class:`McapDepthSink`): per pair, everything :class:`~rig.ros.messages.MessageBuilder` makes
(raw frames, camera infos, rectified views, depth, the pinhole depth of a lat-lon pair, range,
confidence, point cloud), after the
static transform tree; header stamps and log times are the frames' timestamps. A pair whose frame
cannot be read or processed is skipped and reported; the file appears under its name only when
complete.

:class:`McapRecordingWriter` is the recorder's writer for MCAP: each pair's two raw frames, the
camera's JPEG bytes untouched, flushed chunk by chunk (see :mod:`rig.ros.mcap_writer`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from numpy.typing import NDArray

from rig.capture.recorded import RecordedPairs
from rig.errors import OutputError, RecordingError
from rig.pinhole_depth import PinholeDepthConfig
from rig.pipeline import DepthFrame, DepthPipeline
from rig.recording import StoredFrame
from rig.recording_depth import PairFailure, RecordedPair, process_pairs
from rig.rig_depth import RecordedSet, process_sets
from rig.rig_pipeline import RigFrame, RigPipeline
from rig.ros.mcap_writer import Compression, McapRosWriter
from rig.ros.messages import MessageBuilder, raw_image_message
from rig.ros.names import RosNames
from rig.ros.ring_messages import RingMessageBuilder

__all__ = [
    "ExportResult",
    "McapDepthSink",
    "McapRecordingWriter",
    "McapRingSink",
    "export_mcap",
    "export_ring_mcap",
]


@dataclass
class ExportResult:
    path: Path
    pairs: int = 0
    messages: int = 0
    skipped: list[PairFailure] = field(default_factory=list)


class McapDepthSink:
    """An MCAP file as a sink of the staged executor (:data:`rig.recording_depth.PairSink`):
    the static transforms before the first pair, then per pair its two raw frames and everything
    ``builder`` makes of its depth, stamped with the pair's capture times. The writer's failures
    (a full disk) stop the run as :class:`~rig.errors.OutputError`."""

    def __init__(self, writer: McapRosWriter, builder: MessageBuilder) -> None:
        self.writer = writer
        self.builder = builder
        self.pairs = 0

    def __call__(self, pair: RecordedPair, frame: DepthFrame) -> None:
        record, builder = pair.record, self.builder
        assert pair.left is not None and pair.right is not None  # a pair without them has no depth
        try:
            if not self.pairs:
                self.writer.write_all(builder.static(record.left_ts_ns))
            self.writer.write_all(builder.raw_frame("left", pair.left, record.left_ts_ns))
            self.writer.write_all(builder.raw_frame("right", pair.right, record.right_ts_ns))
            self.writer.write_all(builder.depth_outputs(frame, record.left_ts_ns))
        except RecordingError as err:
            raise OutputError(str(err)) from err
        self.pairs += 1


class McapRingSink:
    """An MCAP file as the sink of :func:`rig.rig_depth.process_sets` (a rig of N cameras): the
    static transforms before the first set, then per set every camera's raw frame and everything
    ``builder`` makes of it (:class:`~rig.ros.ring_messages.RingMessageBuilder`: each pair's
    depth, the panorama, the fused cloud), stamped with the set's capture times."""

    def __init__(self, writer: McapRosWriter, builder: RingMessageBuilder) -> None:
        self.writer = writer
        self.builder = builder
        self.sets = 0

    def __call__(self, frame_set: RecordedSet, frame: RigFrame) -> None:
        record, builder = frame_set.record, self.builder
        try:
            if not self.sets:
                self.writer.write_all(builder.static(record.first_ts_ns))
            for camera in builder.cameras:
                stored = frame_set.frames[camera]
                assert stored is not None  # a set without one of its frames has no depth
                self.writer.write_all(builder.raw_frame(camera, stored, record.ts_ns(camera)))
            self.writer.write_all(
                builder.set_outputs(
                    frame.pairs,
                    record.first_ts_ns,
                    panorama=lambda: frame.panorama,
                    fused_cloud=lambda: frame,
                )
            )
        except RecordingError as err:
            raise OutputError(str(err)) from err
        self.sets += 1


def _require_one_written(
    recording: RecordedPairs, written: int, failures: Sequence[PairFailure], unit: str
) -> None:
    """RecordingError naming the first failure when none of the recording's pairs or sets was
    written (an empty recording is not an error)."""
    if recording.pairs and not written:
        first = failures[0]
        raise RecordingError(
            f"{recording.root}: no {unit} of {len(recording.pairs)} could be processed "
            f"(first: seq {first.seq}: {first.reason})"
        )


def export_ring_mcap(
    recording: RecordedPairs,
    ring: RigPipeline,
    out: str | Path,
    *,
    names: RosNames | None = None,
    cloud_stride: int = 1,
    rectified_images: bool = True,
    compression: Compression = "zstd",
    on_set: Callable[[int, PairFailure | None], None] | None = None,
) -> ExportResult:
    """:func:`export_mcap` of a rig of N cameras: every set of ``recording`` through ``ring``
    (:func:`rig.rig_depth.process_sets`) into ``out`` (:class:`McapRingSink`)."""
    builder = RingMessageBuilder(ring, names or RosNames(), cloud_stride, rectified_images)
    with McapRosWriter(out, compression=compression) as writer:
        sink = McapRingSink(writer, builder)
        run = process_sets(ring, recording, recording.pairs, sink, on_set=on_set)
        _require_one_written(recording, run.written, run.failures, "set")
        messages = writer.messages
    return ExportResult(Path(out), run.written, messages, run.failures)


def export_mcap(
    recording: RecordedPairs,
    pipeline: DepthPipeline,
    out: str | Path,
    *,
    names: RosNames | None = None,
    cloud_stride: int = 1,
    rectified_images: bool = True,
    pinhole_depth: PinholeDepthConfig | None = None,
    compression: Compression = "zstd",
    readahead: int = 4,
    on_pair: Callable[[int, PairFailure | None], None] | None = None,
) -> ExportResult:
    """Depth and everything around it for every pair of ``recording`` into ``out`` (see the
    module docstring; ``pinhole_depth``: the pinhole depth image's size and field, the default
    :class:`~rig.pinhole_depth.PinholeDepthConfig` when None). ``on_pair(seq, failure)`` follows
    progress (failure: why it was skipped). RecordingError when no pair could be processed,
    OutputError when the file cannot be written (then no file is left behind)."""
    pinhole = pinhole_depth if pinhole_depth is not None else PinholeDepthConfig()
    builder = MessageBuilder(pipeline, names or RosNames(), cloud_stride, rectified_images, pinhole)
    with McapRosWriter(out, compression=compression) as writer:
        sink = McapDepthSink(writer, builder)
        run = process_pairs(pipeline, recording, recording.pairs, sink, readahead=readahead, on_pair=on_pair)
        _require_one_written(recording, run.written, run.failures, "pair")
        messages = writer.messages
    return ExportResult(Path(out), run.written, messages, run.failures)


class McapRecordingWriter:
    """The recorder's writer (the surface of :class:`~rig.recording.RecordingWriter`) for an
    MCAP file: each pair's raw frames on the raw image topics of ``names``, stamped with their
    capture times, the pair's ``seq`` as the messages' sequence number. Chunks reach the kernel
    as they are written and at least every ``flush_interval_s`` (``fsync``: the device): a killed
    recorder loses at most the chunk in progress, and leaves ``NAME.partial`` for
    :func:`~rig.ros.mcap_writer.recover_mcap`."""

    def __init__(
        self,
        path: str | Path,
        *,
        names: RosNames | None = None,
        cameras: Sequence[str] = ("left", "right"),
        fsync: bool = False,
        compression: Compression = "none",
        chunk_size: int = 1024 * 1024,
        flush_interval_s: float = 1.0,
    ) -> None:
        self.root = Path(path)
        self.names = names or RosNames()
        self.cameras = list(cameras)
        self.count = 0
        self._seqs: set[int] = set()
        self._writer = McapRosWriter(
            self.root,
            compression=compression,
            chunk_size=chunk_size,
            durable=True,
            flush_interval_s=flush_interval_s,
            fsync=fsync,
            exist_ok=False,
        )

    def __enter__(self) -> McapRecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def write_set(self, seq: int, stamps: Sequence[int], frames: Sequence[bytes], ext: str = ".jpg") -> None:
        """One encoded frame per camera (``ext`` .jpg: kept as bytes; .png: written as pixels)."""
        fmt = "png" if ext.lower() == ".png" else "jpeg"
        self._write(seq, stamps, [StoredFrame(fmt, raw=data) for data in frames])

    def write_set_images(self, seq: int, stamps: Sequence[int], images: Sequence[NDArray[Any]]) -> None:
        """One decoded frame per camera (YUYV cameras), as its pixels."""
        self._write(seq, stamps, [StoredFrame("bgr", image=image) for image in images])

    def write_pair(
        self, seq: int, left_ts_ns: int, right_ts_ns: int, left: bytes, right: bytes, ext: str = ".jpg"
    ) -> None:
        """Two encoded frames: :meth:`write_set`."""
        self.write_set(seq, (left_ts_ns, right_ts_ns), (left, right), ext)

    def write_images(
        self, seq: int, left_ts_ns: int, right_ts_ns: int, left: NDArray[Any], right: NDArray[Any]
    ) -> None:
        """Two decoded frames: :meth:`write_set_images`."""
        self.write_set_images(seq, (left_ts_ns, right_ts_ns), (left, right))

    def _write(self, seq: int, stamps: Sequence[int], frames: Sequence[StoredFrame]) -> None:
        if seq in self._seqs or seq < 0:
            raise RecordingError(f"{self.root}: seq {seq} already written or negative")
        if len(stamps) != len(self.cameras) or len(frames) != len(self.cameras):
            raise RecordingError(f"{self.root}: a set holds {len(self.cameras)} frames, got {len(frames)}")
        messages = [
            raw_image_message(self.names, camera, frame, int(ts))
            for camera, frame, ts in zip(self.cameras, frames, stamps, strict=True)
        ]
        self._writer.write_all(messages, sequence=seq)
        self._seqs.add(seq)
        self.count += 1

    def close(self) -> None:
        """Finish the file and move it to its name (a no-op once closed)."""
        self._writer.close()

    def abandon(self) -> None:
        """Stop without finishing, keeping the ``.partial`` file (what a crash leaves)."""
        self._writer.abort(keep=True)
