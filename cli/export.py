"""``rig export mcap REC --out FILE.mcap``: a recording's depth as a ROS 2 MCAP file (see
docs/ros.md): raw frames, camera infos, rectified views, depth, range, confidence, point cloud and
the static transforms, in ROS 2's MCAP profile, written atomically.

REC is a recording directory or a ROS bag (``--left-topic``/``--right-topic``). The depth is
``rig process``'s: the same options, the same calibration check before any pair (an error stops
the command in one line; ``--no-calibration-check`` skips it) and the same executor. A pair whose
frame does not read is reported on stderr and skipped. Exit status 0 when at least one pair was
exported, 2 for bad input (then no file is left behind).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

import typer
from pydantic import ValidationError
from rich.progress import TimeRemainingColumn

from cli.console import RateColumn, console, one_line, progress_bar
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
from cli.source_options import (
    LeftTopicOption,
    MaxSkewOption,
    RightTopicOption,
    TopicOption,
    open_source,
    parse_topics,
)
from rig.errors import ConfigError
from rig.rig_pipeline import RigPipeline
from rig.ros.mcap_export import ExportResult, export_mcap, export_ring_mcap
from rig.ros.names import DepthEncoding, RosNames

if TYPE_CHECKING:
    from rig.capture.recorded import RecordedPairs
    from rig.recording_depth import PairFailure

__all__ = ["register"]


def _names(namespace: str, frame_prefix: str, depth_encoding: DepthEncoding) -> RosNames:
    try:
        return RosNames(namespace=namespace, frame_prefix=frame_prefix, depth_encoding=depth_encoding)
    except ValidationError as err:
        first = err.errors()[0]
        option = {"namespace": "--namespace", "frame_prefix": "--frame-prefix"}.get(str(first["loc"][0]), "")
        raise ConfigError(f"{option}: {first['msg'].removeprefix('Value error, ')}") from None


def register(app: typer.Typer) -> None:
    export = typer.Typer(
        name="export",
        help="Export a recording's depth for other tools (MCAP for ROS 2 and Foxglove).",
        no_args_is_help=True,
    )
    app.add_typer(export)

    @export.command("mcap")
    def mcap(
        recording: Annotated[
            Path,
            typer.Argument(metavar="REC", help="Recording directory, or a ROS bag (MCAP, .db3, bag dir)."),
        ],
        out: Annotated[
            Path, typer.Option("--out", "-o", metavar="FILE", help="MCAP file to write (FILE.mcap).")
        ],
        calibration: CalibrationOption = None,
        left_topic: LeftTopicOption = None,
        right_topic: RightTopicOption = None,
        max_skew_ms: MaxSkewOption = None,
        projection: ProjectionOption = None,
        vpc_hfov: PinholeHfovOption = None,
        vpc_size: PinholeSizeOption = None,
        px_per_deg: PxPerDegOption = None,
        field: FieldOption = None,
        yaw: YawOption = None,
        pitch: PitchOption = None,
        stereo: StereoOption = None,
        depth_encoding: Annotated[
            DepthEncoding,
            typer.Option(
                "--depth-encoding",
                metavar="ENCODING",
                help="32FC1 metres, NaN invalid (REP 118), or 16UC1 mm, 0 invalid.",
            ),
        ] = "32FC1",
        namespace: Annotated[
            str, typer.Option("--namespace", metavar="NS", help="Topic namespace.")
        ] = "/rig",
        frame_prefix: Annotated[
            str, typer.Option("--frame-prefix", metavar="PREFIX", help="Prefix of the frame ids.")
        ] = "rig",
        cloud_stride: Annotated[
            int,
            typer.Option("--cloud-stride", metavar="N", min=1, max=64, help="Every N-th pixel in the cloud."),
        ] = 1,
        rectified_images: Annotated[
            bool,
            typer.Option("--rectified-images/--no-rectified-images", help="Write the rectified (VPC) views."),
        ] = True,
        compression: Annotated[
            Literal["zstd", "lz4", "none"],
            typer.Option(
                "--compression", metavar="COMPRESSION", help="Chunk compression: zstd, lz4 or none."
            ),
        ] = "zstd",
        cache_dir: CacheDirOption = None,
        no_check: NoCheckOption = False,
        topic: TopicOption = None,
    ) -> None:
        """Depth and everything around it for every pair of REC, as a ROS 2 MCAP file (a rig of N
        cameras: every pair's, the panorama and the fused cloud)."""
        names = _names(namespace, frame_prefix, depth_encoding)
        rec = open_source(recording, left_topic, right_topic, max_skew_ms, parse_topics(topic))
        config = make_pair_config(
            vpc_size, vpc_hfov, yaw, pitch, projection=projection, px_per_deg=px_per_deg, field=field
        )
        pipeline, cal_path = build_pipelines(
            calibration, rec.calibration_path, config, stereo, cache_dir, rings=True
        )
        if not no_check:
            check_against_frames(pipeline, rec)
        if isinstance(pipeline, RigPipeline):
            _export_ring(rec, pipeline, out, names, cloud_stride, rectified_images, compression)
            return
        with _export_progress("pairs", len(rec.pairs)) as on_pair:
            result = export_mcap(
                rec,
                pipeline,
                out,
                names=names,
                cloud_stride=cloud_stride,
                rectified_images=rectified_images,
                compression=compression,
                on_pair=on_pair,
            )
        _say_exported(result, len(rec.pairs), "pairs", describe_pipeline(pipeline, cal_path))


def _say_exported(result: ExportResult, total: int, unit: str, what: str) -> None:
    """The export's one summary line: how many of ``total`` pairs or sets, skipped ones, the file,
    its messages and ``what`` they hold."""
    note = f", [yellow]{len(result.skipped)} skipped[/yellow]" if result.skipped else ""
    console.print(
        f"exported {result.pairs} of {total} {unit}{note} -> {result.path} "
        f"({result.messages} messages; {what})",
        highlight=False,
        soft_wrap=True,
    )


@contextmanager
def _export_progress(unit: str, total: int) -> Iterator[Callable[[int, PairFailure | None], None]]:
    """A progress bar over ``total`` pairs or sets and the callback that advances it, printing a
    skipped one's reason above it."""
    with progress_bar(RateColumn(unit), TimeRemainingColumn()) as progress:
        task = progress.add_task("export", total=total)

        def on_item(seq: int, failure: PairFailure | None) -> None:
            if failure is not None:
                progress.console.print(
                    f"[yellow]skipped seq {seq}:[/yellow] {one_line(failure.reason)}",
                    highlight=False,
                    soft_wrap=True,
                )
            progress.advance(task)

        yield on_item


def _export_ring(
    rec: RecordedPairs,
    ring: RigPipeline,
    out: Path,
    names: RosNames,
    cloud_stride: int,
    rectified_images: bool,
    compression: Literal["zstd", "lz4", "none"],
) -> None:
    """``rig export mcap`` of a rig of N cameras (rig.ros.mcap_export.export_ring_mcap)."""
    with _export_progress("sets", len(rec.pairs)) as on_set:
        result = export_ring_mcap(
            rec,
            ring,
            out,
            names=names,
            cloud_stride=cloud_stride,
            rectified_images=rectified_images,
            compression=compression,
            on_set=on_set,
        )
    what = f"pairs {', '.join(ring.labels)}, the panorama and the fused cloud"
    _say_exported(result, len(rec.pairs), "sets", what)
