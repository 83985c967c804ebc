"""`rig process RECORDING --calibration FILE --out DIR`: depth for every pair of a recording,
headless (recording layout: see docs/cameras.md), or of a ROS bag's two image topics (see
docs/ros.md).

Output: ``DIR/depth/NNNNNN.png`` (uint16 mm, 0 = invalid, aligned with the left VPC image),
``DIR/left/NNNNNN.png``, ``DIR/right/NNNNNN.png`` (the VPC images), ``DIR/vpc.json``
(``width, height, fx, fy, cx, cy, baseline_m``); with ``--ply`` also ``DIR/cloud/NNNNNN.ply``
(rig frame), with ``--preview`` ``DIR/preview/NNNNNN.png`` (left VPC beside colour depth).

Before the first pair is processed, the calibration is checked against the first readable pair
(:mod:`rig.calibration_check`): frames of another size, or cameras that look swapped, stop the
command with one line naming the likely cause; a poor fit (rows apart, little overlap or depth)
is a warning, said once.

A pair whose frame file is missing or not a readable image is reported on stderr by sequence
number and skipped. Exit status: 0 when at least one pair was processed (a summary names how
many were skipped), 2 when the calibration, recording or options are bad or no pair could be
processed.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Annotated, Any

import cv2
import numpy as np
import typer
import yaml
from pydantic import ValidationError
from rich.progress import TimeRemainingColumn

from cli.console import console, one_line, progress_bar, warn
from cli.errors import fail
from cli.source_options import LeftTopicOption, MaxSkewOption, RightTopicOption, open_source
from cli.vpc_options import (
    CacheDirOption,
    CalibrationOption,
    PitchOption,
    VpcHfovOption,
    VpcSizeOption,
    YawOption,
    load_calibration,
    make_vpc_config,
)
from rig.calibration_check import check_calibration, check_frame_sizes
from rig.capture.recorded import RecordedPairs
from rig.depth import depth_to_png_mm, write_ply
from rig.errors import ConfigError, PipelineError, RecordingError
from rig.lut import percent_valid
from rig.pipeline import DepthPipeline
from rig.recording import PairRecord
from rig.settings_model import describe_field_errors, field_errors
from rig.stereo import StereoParams
from rig.vpc import VpcConfig

__all__ = ["StereoOption", "build_pipeline", "depth_preview", "load_stereo_params", "register"]

log = logging.getLogger(__name__)


def load_stereo_params(path: Path) -> StereoParams:
    """StereoParams from a YAML/JSON mapping file; ConfigError naming file and field."""
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise ConfigError(f"{path}: unreadable stereo configuration ({err})") from err
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise ConfigError(f"{path}: stereo configuration must be a mapping of parameter names")
    try:
        return StereoParams(**doc)
    except ValidationError as err:
        raise ConfigError(f"{path}: {describe_field_errors(field_errors(err))}") from None


StereoOption = Annotated[
    Path | None, typer.Option("--stereo", metavar="FILE", help="YAML of stereo parameters (ROS names).")
]


def build_pipeline(
    calibration: Path | None,
    fallback: Path | None,
    config: VpcConfig,
    stereo: Path | None,
    cache_dir: Path | None,
) -> tuple[DepthPipeline, Path]:
    """The depth pipeline of the options (calibration, VPC, stereo file, cache), with a warning
    when the VPC leaves a camera's field; and the calibration file used."""
    rig, cal_path = load_calibration(calibration, fallback)
    params = load_stereo_params(stereo) if stereo is not None else None
    pipeline = DepthPipeline(rig, config, params, cache_dir=cache_dir)
    for name, frac in pipeline.valid_fraction.items():
        if frac < 1.0:
            warn(f"the VPC leaves camera '{name}''s field: {percent_valid(frac)} of its pixels are valid")
    return pipeline, cal_path


# Pairs tried for the calibration check before giving up on finding a readable one.
_CHECK_TRIES = 10


def _first_readable(
    rec: RecordedPairs,
) -> tuple[PairRecord, np.ndarray[Any, Any], np.ndarray[Any, Any]] | None:
    for pair in rec.pairs[:_CHECK_TRIES]:
        try:
            left = rec.read_frame(pair, "left").pipeline_image()
            right = rec.read_frame(pair, "right").pipeline_image()
        except RecordingError:
            continue
        return pair, left, right
    return None


def check_against_frames(pipeline: DepthPipeline, rec: RecordedPairs) -> None:
    """The calibration against the recording's first readable pair: an error stops the command
    (one line, exit status 2), each warning is printed once."""
    first = _first_readable(rec)
    if first is None:
        return  # the loop reports every unreadable pair
    pair, left, right = first
    sizes = {
        pipeline.pair.left: (int(left.shape[1]), int(left.shape[0])),
        pipeline.pair.right: (int(right.shape[1]), int(right.shape[0])),
    }
    for problem in check_frame_sizes(pipeline.rig, sizes, f"frames of {rec.root}"):
        fail(problem.message)
    result = check_calibration(pipeline, left, right)
    for problem in result.errors:
        fail(f"calibration check on pair {pair.seq}: {problem.message}")
    for problem in result.warnings:
        warn(f"calibration check on pair {pair.seq}: {problem.message}")


def _write_png(path: Path, image: np.ndarray[Any, Any]) -> None:
    if not cv2.imwrite(str(path), image):
        raise RecordingError(f"{path}: could not write image")


def register(app: typer.Typer) -> None:
    @app.command("process")
    def process(
        recording: Annotated[
            Path,
            typer.Argument(
                metavar="RECORDING",
                help="Recording directory (frames.csv, left/, right/), or a ROS bag (MCAP, .db3, bag dir) "
                "with --left-topic and --right-topic.",
            ),
        ],
        out: Annotated[Path, typer.Option("--out", "-o", metavar="DIR", help="Output directory.")],
        calibration: CalibrationOption = None,
        vpc_hfov: VpcHfovOption = 90.0,
        vpc_size: VpcSizeOption = "640x480",
        yaw: YawOption = 0.0,
        pitch: PitchOption = 0.0,
        stereo: StereoOption = None,
        ply: Annotated[
            bool, typer.Option("--ply", help="Also write DIR/cloud/NNNNNN.ply (rig frame).")
        ] = False,
        preview: Annotated[
            bool,
            typer.Option("--preview", help="Also write DIR/preview/NNNNNN.png (left VPC | colour depth)."),
        ] = False,
        cache_dir: CacheDirOption = None,
        left_topic: LeftTopicOption = None,
        right_topic: RightTopicOption = None,
        max_skew_ms: MaxSkewOption = None,
        no_check: Annotated[
            bool,
            typer.Option(
                "--no-calibration-check", help="Skip the check of the calibration against the frames."
            ),
        ] = False,
    ) -> None:
        """Depth for every pair of RECORDING into --out: depth/, left/, right/ PNGs and vpc.json."""
        rec = open_source(recording, left_topic, right_topic, max_skew_ms)
        config = make_vpc_config(vpc_size, vpc_hfov, yaw, pitch)
        pipeline, cal_path = build_pipeline(calibration, rec.calibration_path, config, stereo, cache_dir)
        if not no_check:
            check_against_frames(pipeline, rec)
        extra = (("cloud",) if ply else ()) + (("preview",) if preview else ())
        dirs = {k: out / k for k in ("depth", "left", "right", *extra)}
        try:
            for d in dirs.values():
                d.mkdir(parents=True, exist_ok=True)
            (out / "vpc.json").write_text(json.dumps(pipeline.pair.as_json(), indent=2) + "\n")
        except OSError as err:
            raise RecordingError(f"{out}: cannot write output ({err.strerror or err})") from err
        done, skipped = 0, 0
        with progress_bar(TimeRemainingColumn()) as progress:
            task = progress.add_task("depth", total=len(rec.pairs))
            for pair in rec.pairs:
                try:
                    left = rec.read_frame(pair, "left").pipeline_image()
                    right = rec.read_frame(pair, "right").pipeline_image()
                    frame = pipeline.process(left, right, pair.seq, pair.left_ts_ns)
                except (RecordingError, PipelineError) as err:
                    skipped += 1
                    progress.console.print(
                        f"[yellow]skipped seq {pair.seq}:[/yellow] {one_line(err)}",
                        highlight=False,
                        soft_wrap=True,
                    )
                    progress.advance(task)
                    continue
                stem = f"{pair.seq:06d}.png"
                _write_png(dirs["depth"] / stem, depth_to_png_mm(frame.depth))
                _write_png(dirs["left"] / stem, frame.left_vpc)
                _write_png(dirs["right"] / stem, frame.right_vpc)
                if preview:
                    _write_png(dirs["preview"] / stem, depth_preview(frame.left_vpc, frame.depth))
                if ply:
                    pts, colors = pipeline.point_cloud(frame)
                    write_ply(dirs["cloud"] / f"{pair.seq:06d}.ply", pts, colors)
                done += 1
                progress.advance(task)
        total = len(rec.pairs)
        if total and not done:
            fail(f"no pair of {total} in {recording} could be processed ({skipped} skipped)")
        note = f", [yellow]{skipped} skipped[/yellow]" if skipped else ""
        console.print(
            f"processed {done} of {total} pairs{note} -> {out} (calibration {cal_path}, "
            f"VPC {config.width}x{config.height} fx {pipeline.pair.fx:.1f}, B {pipeline.baseline_m:.4f} m)",
            highlight=False,
            soft_wrap=True,
        )


def depth_preview(left_vpc: np.ndarray[Any, Any], depth: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
    """Left VPC image beside its depth in colour (turbo on log depth between the 2nd and 98th
    percentiles: near is red, far blue; black = invalid), with that range written on it.
    (H, 2W, 3) uint8 BGR."""
    ok = np.isfinite(depth) & (depth > 0)
    vis = np.zeros((*depth.shape, 3), dtype=np.uint8)
    label = "no depth"
    if ok.any():
        near, far = np.percentile(depth[ok], [2.0, 98.0])
        far = max(far, near * 1.001)
        with np.errstate(invalid="ignore", divide="ignore"):
            t = (np.log(far) - np.log(np.clip(depth, near, far))) / (np.log(far) - np.log(near))
        scaled = np.clip(np.nan_to_num(t, nan=0.0) * 255.0, 0, 255).astype(np.uint8)
        vis = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
        vis[~ok] = 0
        label = f"{near:.2f}-{far:.2f} m"
    left = left_vpc if left_vpc.ndim == 3 else cv2.cvtColor(left_vpc, cv2.COLOR_GRAY2BGR)
    out = np.hstack([left, vis])
    cv2.putText(out, label, (left.shape[1] + 8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2)
    return out
