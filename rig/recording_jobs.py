"""What ``rig process`` works on, here and on a cluster: the recordings (:class:`RecordingSource`,
:class:`RecordingJob`), the run's options (:class:`ProcessOptions`), each recording's plan
(:func:`plan_recording`: its output directory made ready and the pairs to compute and to write
decided) and what a run did (:class:`RecordingSummary`). Shared by :mod:`rig.process` (which runs
the jobs here or hands them to :mod:`rig.cluster`) and :mod:`rig.cluster`; neither imports the
other's callers.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from rig.capture.recorded import RecordedPairs, open_recording
from rig.outputs import BASE_PRODUCTS, OutputLayout, recording_identity
from rig.pipeline import DepthPipeline
from rig.recording import PairRecord
from rig.recording_depth import PairFailure
from rig.rig_pipeline import RigPipeline
from rig.ring_outputs import RingLayout

__all__ = [
    "OnProgress",
    "ProcessOptions",
    "RecordingJob",
    "RecordingSource",
    "RecordingSummary",
    "plan_recording",
    "plan_recordings",
]

OnProgress = Callable[[str, int, Sequence[PairFailure]], None]
"""``on_progress(recording_name, pairs_finished, failures)``: pairs written or failed since the
last call (any thread)."""


@dataclass(frozen=True)
class RecordingSource:
    """Where a recording is and how to open it (a directory, or a ROS bag and its two image
    topics, or a topic per camera of a rig): what a worker on another machine needs to read it."""

    path: Path
    left_topic: str | None = None
    right_topic: str | None = None
    max_skew_ms: float | None = None
    topics: tuple[tuple[str, str], ...] | None = None  # a rig's bag: (camera, topic) each

    @property
    def name(self) -> str:
        """The recording's folder name (a bag file's name without its suffix)."""
        return self.path.stem if self.path.is_file() else self.path.name

    def open(self) -> RecordedPairs:
        return open_recording(
            self.path,
            left_topic=self.left_topic,
            right_topic=self.right_topic,
            max_skew_ms=self.max_skew_ms,
            topics=None if self.topics is None else dict(self.topics),
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
    calibration and its output directory. :func:`plan_recording` fills in the plan. A rig of
    more than two cameras has its ``ring`` pipeline (``pipeline`` is then its first pair's) and
    is written by a :class:`~rig.ring_outputs.RingLayout` (``ring_layout``)."""

    source: RecordingSource
    recording: RecordedPairs
    pipeline: DepthPipeline
    out: Path
    layout: OutputLayout | None = None
    ring: RigPipeline | None = None
    ring_layout: RingLayout | None = None
    compute: list[PairRecord] = field(default_factory=list)  # pairs to run, in order
    write: set[int] = field(default_factory=set)  # seqs whose outputs are written
    resumed: int = 0  # pairs complete before this run

    @property
    def name(self) -> str:
        return self.source.name

    def summary(self, written: int, failures: Sequence[PairFailure]) -> RecordingSummary:
        """What this run did for the job: ``written`` pairs and the ``failures`` among the
        pairs it was to write, by seq."""
        failed = sorted((f for f in failures if f.seq in self.write), key=lambda f: f.seq)
        return RecordingSummary(self.name, self.out, len(self.recording.pairs), written, self.resumed, failed)


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


def plan_recording(job: RecordingJob, options: ProcessOptions) -> None:
    """Get ``job``'s output directory ready and decide which pairs to compute and write."""
    pairs = list(job.recording.pairs)
    seqs = [p.seq for p in pairs]
    where, identity = job.source.path, recording_identity(job.recording)
    if job.ring is not None:
        job.ring_layout = RingLayout(job.out, job.ring, options.products, fsync=options.fsync)
        complete = job.ring_layout.prepare(where, seqs, resume=options.resume, recording_id=identity)
        pipelines = list(job.ring.pipelines.values())
    else:
        job.layout = OutputLayout(job.out, options.products, fsync=options.fsync)
        complete = job.layout.prepare(job.pipeline, where, seqs, resume=options.resume, recording_id=identity)
        pipelines = [job.pipeline]
    todo = [p for p in pairs if p.seq not in complete]
    job.write = {p.seq for p in todo}
    job.resumed = len(complete)
    if todo and any(p.stereo.temporal_alpha > 0.0 for p in pipelines):
        last = pairs.index(todo[-1])
        job.compute = pairs[: last + 1]  # the history the filter needs
    else:
        job.compute = todo


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
