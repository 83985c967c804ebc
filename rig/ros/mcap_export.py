"""MCAP files for ROS 2 and Foxglove: a recording's depth exported (``rig export mcap``), and new
recordings written straight to MCAP (``rig record --format mcap``).

:func:`export_mcap` runs the depth pipeline over every pair of a recording (a directory or a
bag) and writes, per pair, everything :class:`~rig.ros.messages.MessageBuilder` makes (raw
frames, camera infos, rectified views, depth, range, confidence, point cloud), after the static
transform tree; header stamps and log times are the frames' timestamps. A pair whose frame
cannot be read or processed is skipped and reported; the file appears under its name only when
complete.

:class:`McapRecordingWriter` is the recorder's writer for MCAP: each pair's two raw frames, the
camera's JPEG bytes untouched, flushed chunk by chunk (see :mod:`rig.ros.mcap_writer`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from numpy.typing import NDArray

from rig.capture.recorded import RecordedPairs
from rig.errors import PipelineError, RecordingError
from rig.pipeline import DepthPipeline
from rig.process import frame_sizes
from rig.recording import PairRecord, StoredFrame
from rig.ros.mcap_writer import Compression, McapRosWriter
from rig.ros.messages import MessageBuilder, raw_image_message
from rig.ros.names import RosNames

__all__ = ["ExportResult", "McapRecordingWriter", "export_mcap"]


@dataclass
class ExportResult:
    path: Path
    pairs: int = 0
    messages: int = 0
    skipped: list[tuple[int, str]] = field(default_factory=list)


def export_mcap(
    recording: RecordedPairs,
    pipeline: DepthPipeline,
    out: str | Path,
    *,
    names: RosNames | None = None,
    cloud_stride: int = 1,
    rectified_images: bool = True,
    compression: Compression = "zstd",
    on_pair: Callable[[PairRecord, str | None], None] | None = None,
) -> ExportResult:
    """Depth and everything around it for every pair of ``recording`` into ``out`` (see the
    module docstring). ``on_pair(pair, error)`` follows progress (error: why it was skipped).
    RecordingError when no pair could be processed (then no file is left behind)."""
    builder = MessageBuilder(pipeline, names or RosNames(), cloud_stride, rectified_images)
    result = ExportResult(Path(out))
    sizes = frame_sizes(pipeline)
    with McapRosWriter(out, compression=compression) as writer:
        for pair in recording.pairs:
            try:
                left = recording.read_frame(pair, "left")
                right = recording.read_frame(pair, "right")
                images = left.pipeline_image(sizes["left"]), right.pipeline_image(sizes["right"])
                frame = pipeline.process(*images, pair.seq, pair.left_ts_ns)
            except (RecordingError, PipelineError) as err:
                reason = " ".join(str(err).split())
                result.skipped.append((pair.seq, reason))
                if on_pair is not None:
                    on_pair(pair, reason)
                continue
            if not result.pairs:
                writer.write_all(builder.static(pair.left_ts_ns))
            writer.write_all(builder.raw_frame("left", left, pair.left_ts_ns))
            writer.write_all(builder.raw_frame("right", right, pair.right_ts_ns))
            writer.write_all(builder.depth_outputs(frame, pair.left_ts_ns))
            result.pairs += 1
            if on_pair is not None:
                on_pair(pair, None)
        if recording.pairs and not result.pairs:
            raise RecordingError(
                f"{recording.root}: no pair of {len(recording.pairs)} could be processed "
                f"(first: seq {result.skipped[0][0]}: {result.skipped[0][1]})"
            )
        result.messages = writer.messages
    return result


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
        fsync: bool = False,
        compression: Compression = "none",
        chunk_size: int = 1024 * 1024,
        flush_interval_s: float = 1.0,
    ) -> None:
        self.root = Path(path)
        self.names = names or RosNames()
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

    def write_pair(
        self, seq: int, left_ts_ns: int, right_ts_ns: int, left: bytes, right: bytes, ext: str = ".jpg"
    ) -> None:
        """Two encoded frames (``ext`` .jpg: kept as bytes; .png: written as pixels)."""
        fmt = "png" if ext.lower() == ".png" else "jpeg"
        self._write(seq, left_ts_ns, right_ts_ns, StoredFrame(fmt, raw=left), StoredFrame(fmt, raw=right))

    def write_images(
        self, seq: int, left_ts_ns: int, right_ts_ns: int, left: NDArray[Any], right: NDArray[Any]
    ) -> None:
        """Two decoded frames (YUYV cameras), as their pixels."""
        self._write(
            seq, left_ts_ns, right_ts_ns, StoredFrame("bgr", image=left), StoredFrame("bgr", image=right)
        )

    def _write(self, seq: int, lts: int, rts: int, left: StoredFrame, right: StoredFrame) -> None:
        if seq in self._seqs or seq < 0:
            raise RecordingError(f"{self.root}: seq {seq} already written or negative")
        messages = [
            raw_image_message(self.names, "left", left, int(lts)),
            raw_image_message(self.names, "right", right, int(rts)),
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
