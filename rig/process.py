"""Depth for every pair of recordings, written to output directories: ``rig process`` as a
library.

:func:`process_recordings` is the entry point. Each recording (:class:`RecordingJob`) gets its
output directory ready (:class:`rig.outputs.OutputLayout`: with ``resume``, the pairs already
complete are skipped) and its pairs are processed either here, one recording after another, or as
chunks of pairs on a Dask cluster (:mod:`rig.cluster`). Both run :func:`process_pairs`: the
staged pipeline of :mod:`rig.staged` fed by :class:`RecordingReader` (every pair in order, read
ahead on a thread) with a writer stage, so reading, decoding, remapping, matching, finishing and
writing of consecutive pairs overlap on the cores.

The temporal filter (``temporal_alpha`` > 0, off by default) is state that crosses pairs. Its
history is carried: a recording starts with an empty history, and a chunk starts from the one its
predecessor ended with, so the output is the same, bit for bit, however the pairs are split. With
``resume`` and the filter on, the pairs before the last missing one are processed again (not
written) to rebuild that history.

A pair that cannot be read or processed is reported (:class:`PairFailure`) and skipped; an
output directory that cannot be written (a full disk) stops the run with
:class:`~rig.errors.OutputError` and every pair written before stays complete.
"""

from __future__ import annotations

import functools
import queue
import threading
from collections.abc import Callable, Container, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rig.capture.recorded import RecordedPairs, open_recording
from rig.errors import OutputError, RigError
from rig.outputs import BASE_PRODUCTS, OutputLayout, recording_identity
from rig.pipeline import DepthFrame, DepthPipeline
from rig.recording import PairRecord, StoredFrame
from rig.staged import END, EndOfPairs, PairJob, StagedExecutor

__all__ = [
    "OnProgress",
    "PairFailure",
    "PairsResult",
    "ProcessOptions",
    "RecordingJob",
    "RecordingReader",
    "RecordingSource",
    "RecordingSummary",
    "frame_sizes",
    "plan_recording",
    "plan_recordings",
    "process_pairs",
    "process_recordings",
]

_POLL_S = 0.1


@dataclass(frozen=True)
class PairFailure:
    """A pair that produced no output, and why (one line)."""

    seq: int
    reason: str


OnProgress = Callable[[str, int, Sequence[PairFailure]], None]
"""``on_progress(recording_name, pairs_finished, failures)``: pairs written or failed since the
last call (any thread)."""


@dataclass(frozen=True)
class RecordingSource:
    """Where a recording is and how to open it (a directory, or a ROS bag and its two image
    topics): what a worker on another machine needs to read it."""

    path: Path
    left_topic: str | None = None
    right_topic: str | None = None
    max_skew_ms: float | None = None

    @property
    def name(self) -> str:
        """The recording's folder name (a bag file's name without its suffix)."""
        return self.path.stem if self.path.is_file() else self.path.name

    def open(self) -> RecordedPairs:
        return open_recording(
            self.path, left_topic=self.left_topic, right_topic=self.right_topic, max_skew_ms=self.max_skew_ms
        )


@dataclass(frozen=True)
class ProcessOptions:
    """``products``: names of :data:`rig.outputs.PRODUCTS`; ``resume``: skip complete pairs;
    ``readahead``: pairs read ahead of the pipeline; ``chunk_pairs``: pairs per cluster task;
    ``fsync``: force each file to the disk before it is named."""

    products: tuple[str, ...] = BASE_PRODUCTS
    resume: bool = False
    readahead: int = 4
    chunk_pairs: int = 32
    fsync: bool = True


@dataclass
class RecordingJob:
    """One recording to process: its source (opened as ``recording``), the pipeline for its
    calibration and its output directory. :func:`plan_recording` fills in the plan."""

    source: RecordingSource
    recording: RecordedPairs
    pipeline: DepthPipeline
    out: Path
    layout: OutputLayout | None = None
    compute: list[PairRecord] = field(default_factory=list)  # pairs to run, in order
    write: set[int] = field(default_factory=set)  # seqs whose outputs are written
    resumed: int = 0  # pairs complete before this run

    @property
    def name(self) -> str:
        return self.source.name


@dataclass
class RecordingSummary:
    """What a run did for one recording: pairs written now, pairs already complete (resume),
    and the pairs that failed, by seq."""

    name: str
    out: Path
    total: int
    written: int
    resumed: int
    failures: list[PairFailure]


@dataclass
class PairsResult:
    """What :func:`process_pairs` did: pairs written, failures, and the temporal filter's
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
        self._queue: queue.Queue[PairJob[PairRecord] | EndOfPairs] = queue.Queue(maxsize=max(1, readahead))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rig-process-read", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def take(self, timeout_s: float) -> PairJob[PairRecord] | EndOfPairs | None:
        try:
            return self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def _put(self, item: PairJob[PairRecord] | EndOfPairs) -> bool:
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

    def _read(self, pair: PairRecord) -> PairJob[PairRecord]:
        loaders: list[Callable[[], NDArray[Any]]] = []
        for camera in ("left", "right"):
            try:
                stored: StoredFrame = self._recording.read_frame(pair, camera)
                loaders.append(functools.partial(stored.pipeline_image, self._sizes.get(camera)))
            except Exception as err:
                loaders.append(_raiser(err))
        return PairJob(pair, pair.seq, pair.left_ts_ns, loaders[0], loaders[1])


def frame_sizes(pipeline: DepthPipeline) -> dict[str, tuple[int, int]]:
    """The (width, height) the calibration gives the left and right camera's frames."""
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
        return str(err)
    return f"internal error: {type(err).__name__}: {err}"


def process_pairs(
    pipeline: DepthPipeline,
    recording: RecordedPairs,
    pairs: Sequence[PairRecord],
    layout: OutputLayout,
    *,
    write: Container[int] | None = None,
    temporal_state: NDArray[np.float32] | None = None,
    readahead: int = 4,
    on_pair: Callable[[int, PairFailure | None], None] | None = None,
) -> PairsResult:
    """Process ``pairs`` in order through the staged pipeline and write the outputs of those in
    ``write`` (all when None) into ``layout``; the temporal filter starts from
    ``temporal_state``. ``on_pair(seq, failure)`` after each pair of ``write``. Raises
    OutputError when the outputs cannot be written (a full disk) after stopping the stages."""
    lock = threading.Lock()
    failures: list[PairFailure] = []
    written = 0
    fatal: list[BaseException] = []

    def deliver(pair: PairRecord, frame: DepthFrame, timings: dict[str, float]) -> None:
        nonlocal written
        if write is not None and pair.seq not in write:
            return  # computed for the temporal filter's history only
        layout.write(pipeline, frame)
        with lock:
            written += 1
        if on_pair is not None:
            on_pair(pair.seq, None)

    def on_error(pair: PairRecord | None, err: BaseException) -> None:
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
        layout.sync()
    if fatal:
        raise fatal[0]
    failures.sort(key=lambda f: f.seq)
    return PairsResult(written, failures, pipeline.temporal_state())


def plan_recording(job: RecordingJob, options: ProcessOptions) -> None:
    """Get ``job``'s output directory ready and decide which pairs to compute and write."""
    layout = OutputLayout(job.out, options.products, fsync=options.fsync)
    pairs = list(job.recording.pairs)
    complete = layout.prepare(
        job.pipeline,
        job.source.path,
        [p.seq for p in pairs],
        resume=options.resume,
        recording_id=recording_identity(job.recording),
    )
    todo = [p for p in pairs if p.seq not in complete]
    job.layout = layout
    job.write = {p.seq for p in todo}
    job.resumed = len(complete)
    if todo and job.pipeline.stereo.temporal_alpha > 0.0:
        last = pairs.index(todo[-1])
        job.compute = pairs[: last + 1]  # the history the filter needs
    else:
        job.compute = todo


def _summary(job: RecordingJob, written: int, failures: list[PairFailure]) -> RecordingSummary:
    failures = sorted((f for f in failures if f.seq in job.write), key=lambda f: f.seq)
    return RecordingSummary(job.name, job.out, len(job.recording.pairs), written, job.resumed, failures)


def _process_here(
    jobs: Sequence[RecordingJob], options: ProcessOptions, on_progress: OnProgress | None
) -> list[RecordingSummary]:
    summaries = []
    for job in jobs:
        assert job.layout is not None
        name = job.name

        def on_pair(seq: int, failure: PairFailure | None, name: str = name) -> None:
            if on_progress is not None:
                on_progress(name, 1, [failure] if failure is not None else [])

        result = process_pairs(
            job.pipeline,
            job.recording,
            job.compute,
            job.layout,
            write=job.write,
            readahead=options.readahead,
            on_pair=on_pair,
        )
        job.layout.finish()
        summaries.append(_summary(job, result.written, result.failures))
    return summaries


def plan_recordings(
    jobs: Sequence[RecordingJob],
    options: ProcessOptions,
    on_plan: Callable[[Sequence[RecordingJob]], None] | None = None,
) -> None:
    """:func:`plan_recording` for every job, then ``on_plan(jobs)``."""
    for job in jobs:
        plan_recording(job, options)
    if on_plan is not None:
        on_plan(jobs)


def process_recordings(
    jobs: Sequence[RecordingJob],
    options: ProcessOptions | None = None,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    connect_timeout_s: float = 10.0,
    on_plan: Callable[[Sequence[RecordingJob]], None] | None = None,
    on_progress: OnProgress | None = None,
) -> list[RecordingSummary]:
    """Process every job (see the module doc): here when ``scheduler`` is None, else on the Dask
    cluster it names (``"local"``: a LocalCluster of ``workers`` processes; or a scheduler's
    address, which must answer within ``connect_timeout_s``: nothing is written before it
    does). ``on_plan`` sees the jobs once their output directories are ready and their pairs to
    write known (``len(job.write)``)."""
    options = options or ProcessOptions()
    if scheduler is None:
        plan_recordings(jobs, options, on_plan)
        return _process_here(jobs, options, on_progress)
    from rig.cluster import connect, process_on_cluster  # Dask is imported only when a run uses it

    with connect(scheduler, workers=workers, timeout_s=connect_timeout_s) as client:
        plan_recordings(jobs, options, on_plan)
        return process_on_cluster(client, jobs, options, on_progress=on_progress)
