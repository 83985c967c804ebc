"""Depth over a recording's pairs: the staged executor (:mod:`rig.staged`) fed in order by a
:class:`RecordingReader`, into a sink. ``rig process`` (an output directory:
:meth:`rig.outputs.OutputLayout.sink`), its cluster tasks (:func:`rig.cluster.run_chunk`) and
``rig export mcap`` (an MCAP file: :class:`rig.ros.mcap_export.McapDepthSink`) all run
:func:`process_pairs`, so they compute the same depth, bit for bit, report failures alike and
time the stages alike.

The sink gets each pair as a :class:`RecordedPair` (its row and the two stored frames, for a sink
that writes the raw frames too) with its :class:`~rig.pipeline.DepthFrame`, in the recording's
order, on the executor's writer thread. A pair that cannot be read or processed becomes a
:class:`PairFailure`; a sink that raises :class:`~rig.errors.OutputError` (a full disk) stops the
run, and every pair it took before stays complete.
"""

from __future__ import annotations

import functools
import queue
import threading
from collections.abc import Callable, Container, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rig.capture.recorded import RecordedPairs
from rig.errors import OutputError, RigError
from rig.pipeline import DepthFrame, DepthPipeline
from rig.recording import PairRecord, StoredFrame
from rig.staged import END, EndOfPairs, OnError, PairJob, Sink, StagedExecutor

__all__ = [
    "JobsOf",
    "Loader",
    "PairFailure",
    "PairSink",
    "PairsResult",
    "RecordedPair",
    "RecordingReader",
    "RunProgress",
    "frame_sizes",
    "pair_jobs",
    "process_pairs",
]

_POLL_S = 0.1


@dataclass(frozen=True)
class PairFailure:
    """A pair that produced no output, and why (one line)."""

    seq: int
    reason: str


@dataclass(frozen=True)
class RecordedPair:
    """One pair of a recording as the sink gets it: its row and its two frames as stored (None
    for a frame that could not be read: such a pair never reaches a sink)."""

    record: PairRecord
    left: StoredFrame | None
    right: StoredFrame | None

    @property
    def seq(self) -> int:
        return self.record.seq


PairSink = Callable[[RecordedPair, DepthFrame], None]
"""``sink(pair, frame)``: one pair's depth, in the recording's order (:data:`rig.staged.Sink`)."""


@dataclass
class PairsResult:
    """What :func:`process_pairs` did: pairs the sink took, failures, and the temporal filter's
    history after the last pair (None when the filter is off)."""

    written: int
    failures: list[PairFailure]
    temporal_state: NDArray[np.float32] | None


Loader = Callable[[], NDArray[Any]]
JobsOf = Callable[[PairRecord, dict[str, StoredFrame | None], dict[str, Loader]], list[PairJob[Any]]]
"""``jobs_of(row, frames, loaders)``: the executor's jobs for one row of a recording, from its
frames as stored (None: unreadable) and a loader per camera (it raises the read's error)."""


def pair_jobs(
    pair: PairRecord, frames: dict[str, StoredFrame | None], loaders: dict[str, Loader]
) -> list[PairJob[Any]]:
    """A two-camera recording's one job per row: its pair (key :class:`RecordedPair`)."""
    key = RecordedPair(pair, frames["left"], frames["right"])
    return [PairJob(key, pair.seq, pair.first_ts_ns, loaders["left"], loaders["right"])]


class RecordingReader:
    """Reads ``pairs`` of ``recording`` in order on its own thread, at most ``readahead`` jobs
    ahead of the pipeline; :meth:`take` is the staged executor's source. Each row's ``cameras``
    are read (default a pair's, ``left`` and ``right``) and become jobs by ``jobs_of`` (default
    :func:`pair_jobs`). A frame that cannot be read gives a loader that raises that error
    (reported in order)."""

    def __init__(
        self,
        recording: RecordedPairs,
        pairs: Sequence[PairRecord],
        readahead: int = 4,
        sizes: dict[str, tuple[int, int]] | None = None,
        *,
        cameras: Sequence[str] = ("left", "right"),
        jobs_of: JobsOf = pair_jobs,
    ) -> None:
        self._recording = recording
        self._sizes = sizes or {}  # camera -> (width, height) its frames must declare
        self._pairs = list(pairs)
        self._cameras = list(cameras)
        self._jobs_of = jobs_of
        self._queue: queue.Queue[PairJob[Any] | EndOfPairs] = queue.Queue(maxsize=max(1, readahead))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rig-process-read", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def take(self, timeout_s: float) -> PairJob[Any] | EndOfPairs | None:
        try:
            return self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def _put(self, item: PairJob[Any] | EndOfPairs) -> bool:
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        for pair in self._pairs:
            for job in self._read(pair):
                if not self._put(job):
                    return
        self._put(END)

    def _read(self, pair: PairRecord) -> list[PairJob[Any]]:
        frames: dict[str, StoredFrame | None] = {}
        loaders: dict[str, Loader] = {}
        for camera in self._cameras:
            try:
                stored = self._recording.read_frame(pair, camera)
            except Exception as err:
                frames[camera] = None
                loaders[camera] = _raiser(err)
            else:
                frames[camera] = stored
                loaders[camera] = functools.partial(stored.pipeline_image, self._sizes.get(camera))
        return self._jobs_of(pair, frames, loaders)


def frame_sizes(pipeline: DepthPipeline) -> dict[str, tuple[int, int]]:
    """The (width, height) the calibration gives the left and right camera's frames: what a
    frame's header must declare before it is decoded (an image bomb never is)."""
    cameras = pipeline.rig.cameras
    return {
        side: (cameras[name].width, cameras[name].height)
        for side, name in (("left", pipeline.pair.left), ("right", pipeline.pair.right))
    }


def _raiser(err: Exception) -> Callable[[], NDArray[Any]]:
    def load() -> NDArray[Any]:
        raise err

    return load


def _reason(err: BaseException) -> str:
    if isinstance(err, RigError):
        return " ".join(str(err).split())
    return f"internal error: {type(err).__name__}: {err}"


class RunProgress:
    """What a run over a recording did, kept from the executor's threads: rows handed to the
    sink (``written``), rows that failed (``failures``) and errors that stop the run (``fatal``:
    the sink's OutputError, or the source's). ``write``: the seqs whose outputs count (None:
    all); ``on_pair(seq, failure)`` after each of them."""

    def __init__(
        self,
        write: Container[int] | None,
        on_pair: Callable[[int, PairFailure | None], None] | None,
    ) -> None:
        self._write = write
        self._on_pair = on_pair
        self._lock = threading.Lock()
        self.written = 0
        self.failures: list[PairFailure] = []
        self.fatal: list[BaseException] = []

    def wanted(self, seq: int) -> bool:
        return self._write is None or seq in self._write

    def delivered(self, seq: int) -> None:
        with self._lock:
            self.written += 1
        if self._on_pair is not None:
            self._on_pair(seq, None)

    def failed(self, seq: int | None, err: BaseException) -> None:
        """Row ``seq`` failed with ``err`` (None, or an OutputError: the run stops)."""
        if isinstance(err, OutputError) or seq is None:
            with self._lock:
                self.fatal.append(err)
            return
        failure = PairFailure(seq, _reason(err))
        with self._lock:
            self.failures.append(failure)
        if self._on_pair is not None and self.wanted(seq):
            self._on_pair(seq, failure)

    def drive(
        self, pipeline: DepthPipeline, reader: RecordingReader, deliver: Sink, on_error: OnError
    ) -> None:
        """Run the staged executor (``pipeline`` for jobs naming none) on ``reader``'s jobs into
        ``deliver`` until the reader's end, or the first fatal error, which is raised after
        the stages stopped."""
        stages = StagedExecutor(
            pipeline, reader.take, deliver, on_error=on_error, deliver_thread=True, prefix="rig-process"
        )
        reader.start()
        stages.start()
        try:
            while not stages.wait(_POLL_S):
                if self.fatal:
                    break
        finally:
            stages.stop()
            reader.stop()
        if self.fatal:
            raise self.fatal[0]
        self.failures.sort(key=lambda f: f.seq)


def process_pairs(
    pipeline: DepthPipeline,
    recording: RecordedPairs,
    pairs: Sequence[PairRecord],
    sink: PairSink,
    *,
    write: Container[int] | None = None,
    temporal_state: NDArray[np.float32] | None = None,
    readahead: int = 4,
    on_pair: Callable[[int, PairFailure | None], None] | None = None,
) -> PairsResult:
    """Process ``pairs`` in order through the staged executor and hand those in ``write`` (all
    when None) to ``sink``; the temporal filter starts from ``temporal_state`` (None: an empty
    history, as at a recording's start). ``on_pair(seq, failure)`` after each pair of
    ``write``. Raises the sink's OutputError (the outputs cannot be written) after stopping the
    stages."""
    progress = RunProgress(write, on_pair)

    def deliver(pair: RecordedPair, frame: DepthFrame) -> None:
        if not progress.wanted(pair.seq):
            return  # computed for the temporal filter's history only
        sink(pair, frame)
        progress.delivered(pair.seq)

    def on_error(pair: RecordedPair | None, err: BaseException) -> None:
        progress.failed(None if pair is None else pair.seq, err)

    pipeline.restore_temporal_state(temporal_state)
    reader = RecordingReader(recording, pairs, readahead, frame_sizes(pipeline))
    progress.drive(pipeline, reader, deliver, on_error)
    return PairsResult(progress.written, progress.failures, pipeline.temporal_state())
