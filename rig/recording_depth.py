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
from rig.staged import END, EndOfPairs, PairJob, StagedExecutor

__all__ = [
    "PairFailure",
    "PairSink",
    "PairsResult",
    "RecordedPair",
    "RecordingReader",
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


class RecordingReader:
    """Reads ``pairs`` of ``recording`` in order on its own thread, at most ``readahead`` pairs
    ahead of the pipeline; :meth:`take` is the staged executor's source. A pair whose frame
    cannot be read becomes a job whose loader raises that error (reported in order)."""

    def __init__(
        self,
        recording: RecordedPairs,
        pairs: Sequence[PairRecord],
        readahead: int = 4,
        sizes: dict[str, tuple[int, int]] | None = None,
    ) -> None:
        self._recording = recording
        self._sizes = sizes or {}  # camera -> (width, height) its frames must declare
        self._pairs = list(pairs)
        self._queue: queue.Queue[PairJob[RecordedPair] | EndOfPairs] = queue.Queue(maxsize=max(1, readahead))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rig-process-read", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def take(self, timeout_s: float) -> PairJob[RecordedPair] | EndOfPairs | None:
        try:
            return self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def _put(self, item: PairJob[RecordedPair] | EndOfPairs) -> bool:
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        for pair in self._pairs:
            if not self._put(self._read(pair)):
                return
        self._put(END)

    def _read(self, pair: PairRecord) -> PairJob[RecordedPair]:
        frames: list[StoredFrame | None] = []
        loaders = []
        for camera in ("left", "right"):
            try:
                stored = self._recording.read_frame(pair, camera)
            except Exception as err:
                frames.append(None)
                loaders.append(_raiser(err))
            else:
                frames.append(stored)
                loaders.append(functools.partial(stored.pipeline_image, self._sizes.get(camera)))
        key = RecordedPair(pair, frames[0], frames[1])
        return PairJob(key, pair.seq, pair.left_ts_ns, loaders[0], loaders[1])


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
    lock = threading.Lock()
    failures: list[PairFailure] = []
    written = 0
    fatal: list[BaseException] = []

    def deliver(pair: RecordedPair, frame: DepthFrame) -> None:
        nonlocal written
        if write is not None and pair.seq not in write:
            return  # computed for the temporal filter's history only
        sink(pair, frame)
        with lock:
            written += 1
        if on_pair is not None:
            on_pair(pair.seq, None)

    def on_error(pair: RecordedPair | None, err: BaseException) -> None:
        if isinstance(err, OutputError) or pair is None:
            with lock:
                fatal.append(err)
            return
        failure = PairFailure(pair.seq, _reason(err))
        with lock:
            failures.append(failure)
        if on_pair is not None and (write is None or pair.seq in write):
            on_pair(pair.seq, failure)

    pipeline.restore_temporal_state(temporal_state)
    reader = RecordingReader(recording, pairs, readahead, frame_sizes(pipeline))
    stages = StagedExecutor(
        pipeline, reader.take, deliver, on_error=on_error, deliver_thread=True, prefix="rig-process"
    )
    reader.start()
    stages.start()
    try:
        while not stages.wait(_POLL_S):
            if fatal:
                break
    finally:
        stages.stop()
        reader.stop()
    if fatal:
        raise fatal[0]
    failures.sort(key=lambda f: f.seq)
    return PairsResult(written, failures, pipeline.temporal_state())
