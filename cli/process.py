"""`rig process REC... --out DIR`: range (and the pinhole pair's depth) for every pair of one or
many recordings, headless, on the staged pipeline the service runs, here or on a Dask cluster (see
docs/offline.md); the rectified projections: docs/wide-pair.md.

A calibration of more than two cameras (a ring, docs/ring.md) processes every stereo pair of each
synchronised set into ``DIR/<A>-<B>/`` (the layout above) and fuses them into the 360° range
panorama (``DIR/panorama/``, ``DIR/panorama.json``; ``--ply``: the fused cloud in ``DIR/cloud/``),
in this process (:mod:`rig.ring_outputs`).

RECORDING is a recording directory (see docs/cameras.md) or a ROS bag with ``--left-topic`` and
``--right-topic`` (see docs/ros.md); several may be given, or a quoted glob (``'recs/*'``). One
recording's outputs go to DIR, those of several (or of a glob) to ``DIR/NAME/`` (NAME = the
recording folder's name), each in the layout of :mod:`rig.outputs`: ``range/`` (and for the
pinhole pair ``depth/``), ``left/``, ``right/`` PNGs, ``vpc.json`` and ``run.json``; with
``--ply`` ``cloud/``, with ``--preview`` ``preview/``.

Before any pair is processed, each calibration is checked against its recording's first readable
pair (:mod:`rig.calibration_check`): frames of another size, or cameras that look swapped, stop the
command with one line naming the likely cause; a poor fit (rows apart, little overlap or depth)
is a warning, said once.

``--scheduler``: ``none`` (this process, one recording after another; the default for one
recording), ``local`` (a Dask LocalCluster on this machine; the default for several) or a Dask
scheduler's address (``tcp://host:8786``; it must answer within ``--scheduler-timeout``).
``--resume`` skips the pairs whose outputs are complete.

A pair whose frame is missing or not a readable image is reported on stderr by sequence number
and skipped; the summary names how many. Exit status: 0 when every recording gave at least one
pair, 2 when a calibration, recording or option is bad, the scheduler does not answer, the output
cannot be written (a full disk) or a recording gave no pair at all.
"""

from __future__ import annotations

import glob
import hashlib
import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from cli.console import RateColumn, console, err_console, one_line, progress_bar
from cli.errors import fail
from cli.pair_options import (
    CacheDirOption,
    CalibrationOption,
    FieldOption,
    PinholeHfovOption,
    PinholeSizeOption,
    PitchOption,
    ProjectionOption,
    PxPerDegOption,
    YawOption,
    make_pair_config,
)
from cli.pipeline_options import (
    NoCheckOption,
    StereoOption,
    build_pipelines,
    check_against_frames,
    describe_pipeline,
)
from cli.source_options import LeftTopicOption, MaxSkewOption, RightTopicOption, TopicOption, parse_topics
from rig.errors import ConfigError

if TYPE_CHECKING:
    from rig.pipeline import DepthPipeline
    from rig.recording_depth import PairFailure
    from rig.recording_jobs import ProcessOptions, RecordingJob, RecordingSource, RecordingSummary
    from rig.rectified import RectifiedPairConfig
    from rig.rig_pipeline import RigPipeline

__all__ = ["register"]

#: Failures listed per recording in the closing summary (all of them go to --summary FILE).
SUMMARY_LINES = 20


def expand_recordings(arguments: Sequence[Path]) -> tuple[list[Path], bool]:
    """The recordings the arguments name (a quoted glob expanded, sorted), and whether they get
    one output directory each (several, or a glob)."""
    paths: list[Path] = []
    globbed = False
    for arg in arguments:
        text = str(arg)
        if glob.has_magic(text):
            globbed = True
            matches = sorted(glob.glob(text))
            if not matches:
                fail(f"RECORDING {text!r}: no file or directory matches")
            paths += [Path(m) for m in matches]
        else:
            paths.append(arg)
    return paths, globbed or len(paths) > 1


def _output_dirs(sources: Sequence[RecordingSource], out: Path, per_recording: bool) -> list[Path]:
    if not per_recording:
        return [out]
    seen: dict[str, Path] = {}
    for source in sources:
        if source.name in seen:
            fail(f"{seen[source.name]} and {source.path} would both write to {out / source.name}")
        seen[source.name] = source.path
    return [out / s.name for s in sources]


class _Pipelines:
    """One pipeline per calibration (by its file's content): recordings with the same
    calibration share its lookup tables. A rig of more than two cameras has a
    :class:`~rig.rig_pipeline.RigPipeline`."""

    def __init__(
        self,
        calibration: Path | None,
        config: RectifiedPairConfig,
        stereo: Path | None,
        cache: Path | None,
        panorama_px_per_deg: float | None = None,
    ):
        self._options = (calibration, config, stereo, cache)
        self._panorama = panorama_px_per_deg
        self._built: dict[str, DepthPipeline | RigPipeline] = {}

    def for_recording(self, fallback: Path | None) -> tuple[DepthPipeline | RigPipeline, Path]:
        calibration, config, stereo, cache = self._options
        chosen = calibration or fallback
        if chosen is None:
            raise ConfigError("--calibration FILE is required (the recording carries no calibration.yaml)")
        try:
            key = hashlib.sha256(chosen.read_bytes()).hexdigest()
        except OSError as err:
            raise ConfigError(f"{chosen}: unreadable calibration ({err.strerror or err})") from err
        if key not in self._built:
            self._built[key] = build_pipelines(
                calibration, fallback, config, stereo, cache, rings=True, panorama_px_per_deg=self._panorama
            )[0]
        return self._built[key], chosen  # the file this recording names, not the first alike


def _report(summary: RecordingSummary, described: str, unit: str = "pairs") -> None:
    processed = summary.written + summary.resumed
    notes = f", {summary.resumed} already complete" if summary.resumed else ""
    if summary.failures:
        notes += f", [yellow]{len(summary.failures)} skipped[/yellow]"
    console.print(
        f"processed {processed} of {summary.total} {unit}{notes} -> {summary.out} ({described})",
        highlight=False,
        soft_wrap=True,
    )
    for failure in summary.failures[:SUMMARY_LINES]:
        line = f"  failed seq {failure.seq}: {one_line(failure.reason)}"
        err_console.print(line, highlight=False, soft_wrap=True)
    if len(summary.failures) > SUMMARY_LINES:
        err_console.print(f"  ... and {len(summary.failures) - SUMMARY_LINES} more", highlight=False)


def _write_summary(path: Path, summaries: Sequence[RecordingSummary]) -> None:
    from calibration.atomic import write_atomic

    doc = [
        {
            "recording": s.name,
            "out": str(s.out),
            "total": s.total,
            "written": s.written,
            "resumed": s.resumed,
            "failed": [{"seq": f.seq, "reason": f.reason} for f in s.failures],
        }
        for s in summaries
    ]
    try:
        write_atomic(path, json.dumps(doc, indent=2).encode() + b"\n")
    except OSError as err:
        raise ConfigError(f"{path}: cannot write the summary ({err.strerror or err})") from err


def _run(
    jobs: list[RecordingJob],
    options: ProcessOptions,
    scheduler: str | None,
    workers: int | None,
    timeout_s: float,
) -> list[RecordingSummary]:
    """The jobs through :func:`rig.process.process_recordings` under a progress bar."""
    from rig.process import process_recordings

    several = len(jobs) > 1
    from rich.progress import TimeRemainingColumn

    with progress_bar(RateColumn("pairs"), TimeRemainingColumn()) as progress:
        task = progress.add_task("depth" if scheduler is None else f"depth ({scheduler})", total=None)

        def on_plan(planned: Sequence[RecordingJob]) -> None:
            progress.update(task, total=sum(len(j.write) for j in planned))

        def on_progress(name: str, pairs: int, failures: Sequence[PairFailure]) -> None:
            for failure in failures:
                where = f"{name} seq" if several else "seq"
                progress.console.print(
                    f"[yellow]skipped {where} {failure.seq}:[/yellow] {one_line(failure.reason)}",
                    highlight=False,
                    soft_wrap=True,
                )
            progress.advance(task, pairs)

        return process_recordings(
            jobs,
            options,
            scheduler=scheduler,
            workers=workers,
            connect_timeout_s=timeout_s,
            on_plan=on_plan,
            on_progress=on_progress,
        )


def register(app: typer.Typer) -> None:
    @app.command("process")
    def process(
        recordings: Annotated[
            list[Path],
            typer.Argument(
                metavar="RECORDING",
                help="Recording directories (frames.csv, left/, right/) or a quoted glob of them, or ROS "
                "bags (MCAP, .db3, bag dir) with --left-topic and --right-topic.",
            ),
        ],
        out: Annotated[Path, typer.Option("--out", "-o", metavar="DIR", help="Output directory.")],
        calibration: CalibrationOption = None,
        projection: ProjectionOption = None,
        vpc_hfov: PinholeHfovOption = None,
        vpc_size: PinholeSizeOption = None,
        px_per_deg: PxPerDegOption = None,
        field: FieldOption = None,
        yaw: YawOption = None,
        pitch: PitchOption = None,
        stereo: StereoOption = None,
        ply: Annotated[
            bool,
            typer.Option(
                "--ply", help="Also write DIR/cloud/NNNNNN.ply (rig frame; a ring: the fused cloud)."
            ),
        ] = False,
        preview: Annotated[
            bool,
            typer.Option("--preview", help="Also write DIR/preview/NNNNNN.png (left VPC | colour depth)."),
        ] = False,
        cache_dir: CacheDirOption = None,
        left_topic: LeftTopicOption = None,
        right_topic: RightTopicOption = None,
        max_skew_ms: MaxSkewOption = None,
        topic: TopicOption = None,
        resume: Annotated[
            bool, typer.Option("--resume", help="Skip the pairs whose outputs are complete in DIR.")
        ] = False,
        scheduler: Annotated[
            str | None,
            typer.Option(
                "--scheduler",
                metavar="WHERE",
                help="none (this process), local (a Dask LocalCluster here) or a Dask scheduler address "
                "(tcp://host:8786).",
                show_default="none for one recording, local for several",
            ),
        ] = None,
        workers: Annotated[
            int | None,
            typer.Option(
                "--workers",
                min=1,
                metavar="N",
                help="Worker processes of --scheduler local.",
                show_default="one per two cores",
            ),
        ] = None,
        chunk_size: Annotated[
            int, typer.Option("--chunk-size", min=1, metavar="PAIRS", help="Pairs per Dask task.")
        ] = 32,
        scheduler_timeout: Annotated[
            float,
            typer.Option(
                "--scheduler-timeout", min=0.1, metavar="S", help="How long a scheduler may take to answer."
            ),
        ] = 10.0,
        summary: Annotated[
            Path | None,
            typer.Option("--summary", metavar="FILE", help="Also write the summary (every failure) as JSON."),
        ] = None,
        no_check: NoCheckOption = False,
        panorama_px_per_deg: Annotated[
            float | None,
            typer.Option(
                "--panorama-px-per-deg",
                min=0.25,
                max=20.0,
                metavar="PPD",
                help="A ring's 360° panorama: pixels per degree.",
                show_default="4",
            ),
        ] = None,
    ) -> None:
        """Range (and the pinhole pair's depth) for every pair of each RECORDING into --out: range/,
        depth/, left/, right/, vpc.json, run.json. A rig of more than two cameras: that layout in
        --out/<A>-<B>/ per stereo pair, and the 360° range panorama in panorama/ with panorama.json."""
        from rig.recording_jobs import ProcessOptions, RecordingSource

        paths, per_recording = expand_recordings(recordings)
        config = make_pair_config(
            vpc_size, vpc_hfov, yaw, pitch, projection=projection, px_per_deg=px_per_deg, field=field
        )
        topics = parse_topics(topic)
        sources = [RecordingSource(p, left_topic, right_topic, max_skew_ms, topics) for p in paths]
        pipelines = _Pipelines(calibration, config, stereo, cache_dir, panorama_px_per_deg)
        jobs, described = _jobs(sources, _output_dirs(sources, out, per_recording), pipelines, not no_check)
        rings = any(job.ring is not None for job in jobs)
        where = None if rings and scheduler is None else _scheduler(scheduler, len(jobs))
        extra = (("cloud",) if ply else ()) + (("preview",) if preview else ())
        depth = ("depth",) if config.projection == "pinhole" else ()  # the lat-lon pair's depth is its range
        products = ("range", *depth, "left", "right", *extra)
        options = ProcessOptions(products=products, resume=resume, chunk_pairs=chunk_size)
        summaries = _run(jobs, options, where, workers, scheduler_timeout)
        for result, text, job in zip(summaries, described, jobs, strict=True):
            _report(result, text, "sets" if job.ring is not None else "pairs")
        if summary is not None:
            _write_summary(summary, summaries)
        empty = [
            (s, j) for s, j in zip(summaries, jobs, strict=True) if s.total and not s.written + s.resumed
        ]
        if empty:
            s, job = empty[0]
            fail(f"no pair of {s.total} in {job.source.path} could be processed ({len(s.failures)} skipped)")


def _jobs(
    sources: Sequence[RecordingSource], outs: Sequence[Path], pipelines: _Pipelines, check: bool
) -> tuple[list[RecordingJob], list[str]]:
    """One job per recording (each opened, and its calibration checked against its frames,
    first: a bad one stops the command before any work), and the line describing its
    calibration and rectified pair."""
    from rig.recording_jobs import RecordingJob

    opened = [source.open() for source in sources]
    jobs, described = [], []
    from rig.rig_depth import check_recording_cameras
    from rig.rig_pipeline import RigPipeline

    for source, recording, out_dir in zip(sources, opened, outs, strict=True):
        pipeline, cal_path = pipelines.for_recording(recording.calibration_path)
        if check:
            check_against_frames(pipeline, recording)
        if isinstance(pipeline, RigPipeline):
            check_recording_cameras(recording, pipeline.cameras)
            jobs.append(RecordingJob(source, recording, pipeline.first, out_dir, ring=pipeline))
        else:
            jobs.append(RecordingJob(source, recording, pipeline, out_dir))
        described.append(describe_pipeline(pipeline, cal_path))
    return jobs, described


def _scheduler(option: str | None, recordings: int) -> str | None:
    """None (this process), ``local`` or an address, from ``--scheduler``."""
    if option is None:
        return "local" if recordings > 1 else None
    if option.lower() == "none":
        return None
    if option.lower() == "local" or "://" in option:
        return option.lower() if option.lower() == "local" else option
    raise ConfigError(f"--scheduler: expected none, local or an address like tcp://host:8786, got {option!r}")
