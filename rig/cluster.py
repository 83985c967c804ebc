"""``rig process`` on a Dask distributed cluster: chunks of pairs as tasks.

Each recording's pairs to compute (:func:`rig.recording_jobs.plan_recording`) are cut into chunks
of consecutive pairs; each chunk is one task, :func:`run_chunk`, which runs
:func:`rig.recording_depth.process_pairs` on a worker and writes its pairs' files straight into the
recording's output directory (atomically: a task that dies mid-write leaves only a temporary,
removed when the recording is done). The client plans, submits and collects; it reads no frame.

**Lookup tables** are built (or loaded from the cache) once per calibration in the client and
shipped to every worker with ``Client.scatter(..., broadcast=True)`` inside a
:class:`PipelineSpec` (calibration, VPC and stereo settings, both tables); a worker builds its
pipeline from them on its first chunk and keeps it for the next. Scattered rather than shared
through the LUT cache: workers on other machines share no cache directory, and a 640×480 table
pair (2 × 15 bytes per pixel, 9.2 MB) crosses the network once per worker, not per task.

**The temporal filter** (off by default) makes a chunk depend on the one before it: with it on,
each chunk of a recording is submitted with its predecessor's result as an argument and starts
from the filter history that one ended with, so one recording's chunks run one after another
(recordings still spread over the workers). With it off, chunks are independent.

**Failures**: a task whose worker dies is rescheduled by the scheduler on another worker; after
``distributed.scheduler.allowed-failures`` deaths (3) its pairs are reported failed with that
reason. A chunk that raises fails its pairs with the reason; an :class:`~rig.errors.OutputError`
(a full disk) stops the whole run.

Every worker must see the recordings and the output directories at the same paths (a shared file
system); :func:`process_on_cluster` checks that before submitting anything.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import math
import os
import socket
import threading
import uuid
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from calibration.rig import Rig
from rig.capture.recorded import RecordedPairs
from rig.errors import ClusterError, OutputError
from rig.lut_cache import CachedLut
from rig.outputs import OutputLayout
from rig.pipeline import DepthPipeline
from rig.recording import PairRecord
from rig.recording_depth import PairFailure, process_pairs
from rig.recording_jobs import OnProgress, ProcessOptions, RecordingJob, RecordingSource, RecordingSummary
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams

__all__ = [
    "Chunk",
    "ChunkResult",
    "PipelineSpec",
    "connect",
    "default_local_workers",
    "local_cluster",
    "plan_chunks",
    "process_on_cluster",
    "run_chunk",
]

log = logging.getLogger(__name__)

_RECORDINGS_KEPT = 8  # opened recordings a worker keeps (a bag's index reads the whole bag)


def default_local_workers() -> int:
    """Worker processes of ``--scheduler local``: one per two cores (each chunk runs the staged
    pipeline, whose threads keep about two cores busy), at least one."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, cores // 2)


@dataclass(frozen=True)
class PipelineSpec:
    """What a worker needs to build the pipeline of one calibration: shipped once per worker."""

    rig: Rig
    vpc: RectifiedPairConfig
    stereo: StereoParams
    luts: dict[str, CachedLut]

    @classmethod
    def of(cls, pipeline: DepthPipeline) -> PipelineSpec:
        return cls(pipeline.rig, pipeline.pair_config, pipeline.stereo, dict(pipeline.lut_info))

    @property
    def key(self) -> str:
        """Identifies the pipeline within a worker process: the tables' and settings' content."""
        doc = [sorted((n, info.key) for n, info in self.luts.items()), self.vpc.model_dump_json()]
        doc.append(self.stereo.model_dump_json())
        return hashlib.sha256(repr(doc).encode()).hexdigest()

    def build(self) -> DepthPipeline:
        return DepthPipeline(self.rig, self.vpc, self.stereo, luts=self.luts)


@dataclass(frozen=True)
class Chunk:
    """One task: consecutive ``pairs`` of a recording, the outputs of ``write`` written."""

    source: RecordingSource
    out: Path
    products: tuple[str, ...]
    fsync: bool
    readahead: int
    index: int
    pairs: tuple[PairRecord, ...]
    write: frozenset[int]


@dataclass
class ChunkResult:
    """What one chunk did, where (``worker``: host and process id), and the temporal filter's
    history after its last pair (None with the filter off)."""

    name: str
    index: int
    written: int
    failures: list[PairFailure]
    temporal_state: NDArray[np.float32] | None
    worker: str


# ----- the worker side ---------------------------------------------------------------------------
_lock = threading.Lock()
_idle_pipelines: dict[str, list[DepthPipeline]] = {}
_recordings: OrderedDict[RecordingSource, RecordedPairs] = OrderedDict()


@contextlib.contextmanager
def _borrowed_pipeline(spec: PipelineSpec) -> Iterator[DepthPipeline]:
    """A pipeline of ``spec`` for this task alone (a worker running tasks on several threads
    builds one per thread), kept for the worker's next task."""
    key = spec.key
    with _lock:
        idle = _idle_pipelines.setdefault(key, [])
        pipeline = idle.pop() if idle else None
    if pipeline is None:
        pipeline = spec.build()
    try:
        yield pipeline
    finally:
        with _lock:
            _idle_pipelines[key].append(pipeline)


def _open(source: RecordingSource) -> RecordedPairs:
    with _lock:
        recording = _recordings.get(source)
        if recording is not None:
            _recordings.move_to_end(source)
            return recording
    recording = source.open()
    with _lock:
        _recordings[source] = recording
        while len(_recordings) > _RECORDINGS_KEPT:
            _recordings.popitem(last=False)
    return recording


def run_chunk(spec: PipelineSpec, chunk: Chunk, previous: ChunkResult | None = None) -> ChunkResult:
    """The task: process ``chunk`` on this worker, starting from ``previous``'s temporal
    history (the chunk before it, with the temporal filter on)."""
    layout = OutputLayout(chunk.out, chunk.products, fsync=chunk.fsync)
    state = previous.temporal_state if previous is not None else None
    with _borrowed_pipeline(spec) as pipeline:
        try:
            result = process_pairs(
                pipeline,
                _open(chunk.source),
                chunk.pairs,
                layout.sink(pipeline),
                write=chunk.write,
                temporal_state=state,
                readahead=chunk.readahead,
            )
        finally:
            layout.sync()
    return ChunkResult(
        chunk.source.name,
        chunk.index,
        result.written,
        result.failures,
        result.temporal_state if spec.stereo.temporal_alpha > 0.0 else None,
        f"{socket.gethostname()}:{os.getpid()}",
    )


def _missing_paths(paths: Sequence[str]) -> list[str]:
    """Run on every worker: the paths it cannot see."""
    return [p for p in paths if not os.path.exists(p)]


# ----- the client side ---------------------------------------------------------------------------
def local_cluster(workers: int | None = None) -> Any:
    """A new Dask LocalCluster on this machine: ``workers`` processes of one thread each
    (:func:`default_local_workers` by default; the pipeline's stages bring their own threads),
    no dashboard, only errors logged."""
    from distributed import LocalCluster

    return LocalCluster(
        n_workers=workers or default_local_workers(),
        threads_per_worker=1,
        processes=True,
        dashboard_address=None,
        # The scheduler's HTTP routes on a free loopback port: not 8787, which another
        # cluster on a shared machine may hold.
        scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"},
        silence_logs=logging.ERROR,
    )


@contextlib.contextmanager
def connect(scheduler: str, *, workers: int | None = None, timeout_s: float = 10.0) -> Iterator[Any]:
    """A ``distributed.Client``: of a new LocalCluster (``scheduler == "local"``: ``workers``
    processes of one thread each, :func:`default_local_workers` by default) or of the scheduler
    at an address (``tcp://host:8786``), which must answer and have a worker within
    ``timeout_s``; ClusterError in one line otherwise."""
    from distributed import Client

    if scheduler == "local":
        with local_cluster(workers) as cluster, Client(cluster) as client:
            yield client
        return
    try:
        client = Client(scheduler, timeout=timeout_s)
    except (OSError, TimeoutError, ValueError) as err:
        raise ClusterError(
            f"{scheduler}: no Dask scheduler answered within {timeout_s:g} s ({' '.join(str(err).split())})"
        ) from err
    with client:
        try:
            client.wait_for_workers(1, timeout=timeout_s)
        except TimeoutError as err:
            raise ClusterError(
                f"{scheduler}: the scheduler answers but no worker joined within {timeout_s:g} s"
            ) from err
        yield client


def plan_chunks(job: RecordingJob, options: ProcessOptions, workers: int) -> list[Chunk]:
    """``job``'s pairs to compute in chunks of ``options.chunk_pairs`` (fewer, when that would
    leave workers idle on a short recording)."""
    pairs = job.compute
    size = max(1, min(options.chunk_pairs, math.ceil(len(pairs) / max(1, workers))))
    chunks = []
    for index, start in enumerate(range(0, len(pairs), size)):
        part = tuple(pairs[start : start + size])
        chunks.append(
            Chunk(
                job.source,
                job.out,
                options.products,
                options.fsync,
                options.readahead,
                index,
                part,
                frozenset(p.seq for p in part if p.seq in job.write),
            )
        )
    return chunks


def _check_paths(client: Any, jobs: Sequence[RecordingJob]) -> None:
    paths = sorted({str(j.source.path.resolve()) for j in jobs} | {str(j.out.resolve()) for j in jobs})
    for worker, missing in client.run(_missing_paths, paths).items():
        if missing:
            raise ClusterError(
                f"worker {worker} cannot see {missing[0]}: the recordings and --out must be on a file "
                "system every worker mounts at the same path"
            )


def _failed_chunk(chunk: Chunk, err: BaseException) -> list[PairFailure]:
    from distributed import KilledWorker

    if isinstance(err, KilledWorker):
        reason = f"the worker processing its chunk died too often ({' '.join(str(err).split())})"
    elif isinstance(err, OutputError | ClusterError):
        reason = str(err)
    else:
        reason = f"its chunk failed: {type(err).__name__}: {' '.join(str(err).split())}"
    return [PairFailure(seq, reason) for seq in sorted(chunk.write)]


def _submit(client: Any, jobs: Sequence[RecordingJob], options: ProcessOptions) -> dict[Any, _Submitted]:
    """Scatter each calibration's :class:`PipelineSpec` once and submit every chunk."""
    n_workers = max(1, len(client.scheduler_info().get("workers", {})))
    specs: dict[int, Any] = {}
    pending: dict[Any, _Submitted] = {}
    run_id = uuid.uuid4().hex[:8]
    for job in jobs:
        if id(job.pipeline) not in specs:
            spec = PipelineSpec.of(job.pipeline)
            specs[id(job.pipeline)] = client.scatter(spec, broadcast=True, hash=False)
        temporal = job.pipeline.stereo.temporal_alpha > 0.0
        previous = None
        for chunk in plan_chunks(job, options, n_workers):
            key = f"rig-chunk-{job.name}-{chunk.index}-{run_id}"
            future = client.submit(run_chunk, specs[id(job.pipeline)], chunk, previous, key=key, pure=False)
            pending[future] = _Submitted(job, chunk)
            previous = future if temporal else None
    return pending


@dataclass
class _Submitted:
    job: RecordingJob
    chunk: Chunk


@dataclass
class _Tally:
    written: int = 0
    failures: list[PairFailure] = field(default_factory=list)


def _collect(pending: dict[Any, _Submitted], on_progress: OnProgress | None) -> dict[int, _Tally]:
    """Each chunk's outcome as it completes (by ``id`` of its job); an OutputError stops it."""
    from distributed import as_completed

    tallies: dict[int, _Tally] = {}
    for future in as_completed(list(pending)):
        job, chunk = pending[future].job, pending[future].chunk
        tally = tallies.setdefault(id(job), _Tally())
        if future.status == "error":
            err = future.exception()
            if isinstance(err, OutputError):
                raise err
            failures = _failed_chunk(chunk, err)
        else:
            result: ChunkResult = future.result()
            tally.written += result.written
            failures = [f for f in result.failures if f.seq in chunk.write]
        tally.failures += failures
        if on_progress is not None:
            on_progress(job.name, len(chunk.write), failures)
    return tallies


def process_on_cluster(
    client: Any,
    jobs: Sequence[RecordingJob],
    options: ProcessOptions,
    *,
    on_progress: OnProgress | None = None,
) -> list[RecordingSummary]:
    """Every planned job's chunks on the cluster of ``client`` (a ``distributed.Client``, see
    the module doc); the summaries in the order of ``jobs``."""
    _check_paths(client, jobs)
    pending = _submit(client, jobs, options)
    try:
        tallies = _collect(pending, on_progress)
    finally:
        client.cancel(list(pending))
    summaries = []
    for job in jobs:
        assert job.layout is not None
        job.layout.close()  # no task writes there any more: remove what a killed one left
        tally = tallies.get(id(job), _Tally())
        summaries.append(job.summary(tally.written, tally.failures))
    return summaries
