"""Depth for every pair of recordings, written to output directories: ``rig process`` as a
library.

:func:`process_recordings` is the entry point. Each recording (:class:`rig.recording_jobs.RecordingJob`)
gets its output directory ready (:func:`rig.recording_jobs.plan_recording`: with ``resume``, the
pairs already complete are skipped) and its pairs are processed either here, one recording after
another, or as chunks of pairs on a Dask cluster (:mod:`rig.cluster`). Both run
:func:`rig.recording_depth.process_pairs`: the staged executor of :mod:`rig.staged` fed by a
recording reader (every pair in order, read ahead on a thread) with the output directory as its
sink on a writer stage, so reading, decoding, remapping, matching, post-processing and writing of
consecutive pairs overlap on the cores.

The temporal filter (``temporal_alpha`` > 0, off by default) is state that crosses pairs. Its
history is carried: a recording starts with an empty history, and a chunk starts from the one its
predecessor ended with, so the output is the same, bit for bit, however the pairs are split. With
``resume`` and the filter on, the pairs before the last missing one are processed again (not
written) to rebuild that history.

A rig of more than two cameras (``RecordingJob.ring``) is processed set by set here
(:func:`rig.rig_depth.process_sets`), into its pairs' directories and the panorama
(:class:`rig.ring_outputs.RingLayout`).

A pair that cannot be read or processed is reported (:class:`~rig.recording_depth.PairFailure`)
and skipped; an output directory that cannot be written (a full disk) stops the run with
:class:`~rig.errors.OutputError` and every pair written before stays complete.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from rig.errors import ConfigError
from rig.outputs import OutputLayout
from rig.recording_depth import PairFailure, PairsResult, process_pairs
from rig.recording_jobs import OnProgress, ProcessOptions, RecordingJob, RecordingSummary, plan_recordings
from rig.rig_depth import process_sets
from rig.ring_outputs import RingLayout

__all__ = ["process_recordings"]


def _process_here(
    jobs: Sequence[RecordingJob], options: ProcessOptions, on_progress: OnProgress | None
) -> list[RecordingSummary]:
    summaries = []
    for job in jobs:
        name = job.name

        def on_pair(seq: int, failure: PairFailure | None, name: str = name) -> None:
            if on_progress is not None:
                on_progress(name, 1, [failure] if failure is not None else [])

        result = _process_job(job, options, on_pair)
        summaries.append(job.summary(result.written, result.failures))
    return summaries


def _process_job(
    job: RecordingJob, options: ProcessOptions, on_pair: Callable[[int, PairFailure | None], None]
) -> PairsResult:
    """One recording's pairs (or a ring's sets) through the staged executor into its outputs."""
    if job.ring is not None:
        ring, ring_layout = job.ring, job.ring_layout
        assert ring_layout is not None
        return _written(
            ring_layout,
            lambda: process_sets(
                ring,
                job.recording,
                job.compute,
                ring_layout.sink(),
                write=job.write,
                readahead=2 * options.readahead,
                on_set=on_pair,
            ),
        )
    layout = job.layout
    assert layout is not None
    return _written(
        layout,
        lambda: process_pairs(
            job.pipeline,
            job.recording,
            job.compute,
            layout.sink(job.pipeline),
            write=job.write,
            readahead=options.readahead,
            on_pair=on_pair,
        ),
    )


def _written(layout: OutputLayout | RingLayout, run: Callable[[], PairsResult]) -> PairsResult:
    """``run()`` into ``layout``: its renames made durable whatever happens, then closed."""
    try:
        result = run()
    finally:
        layout.sync()
    layout.close()
    return result


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
    rings = [job.name for job in jobs if job.ring is not None]
    if scheduler is not None and rings:
        raise ConfigError(
            f"--scheduler {scheduler}: {rings[0]} is a recording of a rig of more than two cameras; "
            "its sets are processed in this process (--scheduler none)"
        )
    if scheduler is None:
        plan_recordings(jobs, options, on_plan)
        return _process_here(jobs, options, on_progress)
    from rig.cluster import connect, process_on_cluster  # Dask is imported only when a run uses it

    with connect(scheduler, workers=workers, timeout_s=connect_timeout_s) as client:
        plan_recordings(jobs, options, on_plan)
        return process_on_cluster(client, jobs, options, on_progress=on_progress)
