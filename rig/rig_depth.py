"""Depth over a recording of N cameras: every stereo pair of each frame set through the one staged
executor (:mod:`rig.staged`), then the set's panorama, into a sink. ``rig process`` on a ring
(an output directory: :class:`rig.ring_outputs.RingLayout`) and ``rig export mcap`` on a ring
run :func:`process_sets`.

The recording reader (:class:`rig.recording_depth.RecordingReader`) reads each set's frames once
and hands the executor one job per pair, each naming its pair's pipeline; a camera's image is
decoded once per set, by the first pair that needs it. The pairs of a set leave the executor in
order; when the last one is finished the set's panorama is fused (on the executor's writer
thread) and the sink gets the set as a :class:`RecordedSet` with its
:class:`~rig.rig_pipeline.RigFrame`. A set one of whose pairs cannot be read or processed is
reported by its seq (:class:`~rig.recording_depth.PairFailure`) and skipped whole: no sink sees
part of a set.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Container, Sequence
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar, overload

from numpy.typing import NDArray

from calibration.rig import Rig
from rig.capture.recorded import RecordedPairs
from rig.errors import RecordingError
from rig.frame_sets import FrameSetRecord
from rig.pipeline import DepthFrame
from rig.recording import Recording
from rig.recording_depth import Loader, PairFailure, PairsResult, RecordingReader, RunProgress
from rig.rig_pipeline import RigFrame, RigPipeline
from rig.staged import PairJob
from rig.stored_frame import StoredFrame

__all__ = [
    "OpenSet",
    "RecordedSet",
    "RecordingFrames",
    "RigSink",
    "SetCollector",
    "check_recording_cameras",
    "process_sets",
    "read_set_images",
]


@dataclass(frozen=True, eq=False)
class RecordedSet:
    """One frame set of a recording as the sink gets it: its row and its frames as stored."""

    record: FrameSetRecord
    frames: dict[str, StoredFrame | None]

    @property
    def seq(self) -> int:
        return self.record.seq


RigSink = Callable[[RecordedSet, RigFrame], None]
S = TypeVar("S")
"""``sink(frame_set, rig_frame)``: one set's depth and panorama, in the recording's order."""


@dataclass(frozen=True, eq=False)
class _Part:
    """One pair of a set: the executor's key of its job."""

    set: RecordedSet
    label: str


class _OnceImages:
    """A set's loaders, each run at most once whichever pair asks first (thread-safe)."""

    def __init__(self, loaders: dict[str, Loader]) -> None:
        self._loaders = loaders
        self._images: dict[str, NDArray[Any]] = {}
        self._lock = threading.Lock()

    def loader(self, camera: str) -> Loader:
        def load() -> NDArray[Any]:
            with self._lock:
                if camera not in self._images:
                    self._images[camera] = self._loaders[camera]()
                return self._images[camera]

        return load


@dataclass
class OpenSet(Generic[S]):
    """A set whose pairs are not all back yet: ``set`` the caller's (its row, its frames)."""

    set: S
    frames: dict[str, DepthFrame] = field(default_factory=dict)
    error: BaseException | None = None
    resolved: int = 0


class SetCollector(Generic[S]):
    """Collects each set's ``pairs`` pairs (finished or failed, in whatever order they come back
    from the executor's threads); thread-safe."""

    def __init__(self, pairs: int) -> None:
        self._pairs = pairs
        self._open: dict[int, OpenSet[S]] = {}
        self._lock = threading.Lock()

    def resolve(
        self, seq: int, whole: S, label: str, frame: DepthFrame | None, err: BaseException | None
    ) -> OpenSet[S] | None:
        """Note pair ``label`` of set ``seq`` (``whole``): its frame, or its error; the set once
        all its pairs are back, else None."""
        with self._lock:
            entry = self._open.setdefault(seq, OpenSet(whole))
            if frame is not None:
                entry.frames[label] = frame
            elif entry.error is None:
                entry.error = err
            entry.resolved += 1
            if entry.resolved < self._pairs:
                return None
            del self._open[seq]
            return entry


def check_recording_cameras(recording: RecordedPairs, cameras: Sequence[str]) -> None:
    """RecordingError naming the recording's file and field when it lacks one of ``cameras``."""
    missing = [c for c in cameras if c not in recording.cameras]
    if missing:
        where = recording.root / "recording.json" if isinstance(recording, Recording) else recording.root
        raise RecordingError(
            f"{where}: field 'cameras': no camera {', '.join(map(repr, missing))} of the calibration "
            f"(the recording has {', '.join(recording.cameras)})"
        )


def _set_sizes(rig: RigPipeline) -> dict[str, tuple[int, int]]:
    return {n: (rig.rig.cameras[n].width, rig.rig.cameras[n].height) for n in rig.cameras}


def process_sets(
    rig: RigPipeline,
    recording: RecordedPairs,
    sets: Sequence[FrameSetRecord],
    sink: RigSink,
    *,
    write: Container[int] | None = None,
    readahead: int = 8,
    on_set: Callable[[int, PairFailure | None], None] | None = None,
) -> PairsResult:
    """Process ``sets`` in order (see the module doc) and hand those in ``write`` (all when
    None) to ``sink``; every pair's temporal filter starts with an empty history.
    ``on_set(seq, failure)`` after each set of ``write``. RecordingError when the recording
    lacks a camera of the pairs; the sink's OutputError (the outputs cannot be written) stops
    the run."""
    check_recording_cameras(recording, rig.cameras)
    progress = RunProgress(write, on_set)
    collected: SetCollector[RecordedSet] = SetCollector(len(rig.pipelines))

    def jobs_of(
        row: FrameSetRecord, frames: dict[str, StoredFrame | None], loaders: dict[str, Loader]
    ) -> list[PairJob[Any]]:
        images = _OnceImages(loaders)
        recorded = RecordedSet(row, frames)
        return [
            PairJob(
                _Part(recorded, label),
                row.seq,
                row.first_ts_ns,
                images.loader(p.names[0]),
                images.loader(p.names[1]),
                pipeline=p,
            )
            for label, p in rig.pipelines.items()
        ]

    def finished(part: _Part, frame: DepthFrame | None, err: BaseException | None) -> None:
        entry = collected.resolve(part.set.seq, part.set, part.label, frame, err)
        if entry is None:
            return
        seq = entry.set.seq
        if entry.error is not None:
            progress.failed(seq, entry.error)
            return
        if not progress.wanted(seq):
            return  # computed for the temporal filters' history only
        try:
            sink(entry.set, rig.finish(entry.frames, seq, entry.set.record.first_ts_ns))
        except Exception as sink_err:
            progress.failed(seq, sink_err)
            return
        progress.delivered(seq)

    def on_error(part: _Part | None, err: BaseException) -> None:
        if part is None:
            progress.failed(None, err)
        else:
            finished(part, None, err)

    for p in rig.pipelines.values():
        p.restore_temporal_state(None)
    reader = RecordingReader(
        recording, sets, readahead, _set_sizes(rig), cameras=rig.cameras, jobs_of=jobs_of
    )
    progress.drive(rig.first, reader, lambda part, frame: finished(part, frame, None), on_error)
    return PairsResult(progress.written, progress.failures, None)


def read_set_images(
    recording: RecordedPairs, row: FrameSetRecord, rig: Rig, cameras: Sequence[str]
) -> dict[str, NDArray[Any]]:
    """The images of ``cameras`` in one row as the pipeline takes them (uint8), each frame's
    size checked against ``rig``'s calibration before it is decoded."""
    return {
        c: recording.read_frame(row, c).pipeline_image((rig.cameras[c].width, rig.cameras[c].height))
        for c in cameras
    }


class RecordingFrames(Sequence[dict[str, NDArray[Any]]]):
    """The sets of a recording as images, read when asked for (one set in memory at a time):
    the ``frames`` a library function over sets takes (e.g.
    :func:`rig.evaluate.consistency_study.consistency_study`). RecordingError naming the frame
    when one cannot be read."""

    def __init__(self, recording: RecordedPairs, rig: Rig, cameras: Sequence[str]) -> None:
        check_recording_cameras(recording, cameras)
        self._recording, self._rig, self._cameras = recording, rig, list(cameras)

    def __len__(self) -> int:
        return len(self._recording.pairs)

    @overload
    def __getitem__(self, index: int) -> dict[str, NDArray[Any]]: ...

    @overload
    def __getitem__(self, index: slice) -> list[dict[str, NDArray[Any]]]: ...

    def __getitem__(self, index: int | slice) -> dict[str, NDArray[Any]] | list[dict[str, NDArray[Any]]]:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        row = self._recording.pairs[index]
        return read_set_images(self._recording, row, self._rig, self._cameras)
