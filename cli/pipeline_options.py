"""The depth pipeline of the command line's options, shared by the commands that run depth over a
recording (``rig process``, ``rig export mcap``) and those that take a stereo file (``rig sim``):
the stereo file (:func:`load_stereo_params`), the pipeline with its one warning line per thing the
rectified view leaves out (:func:`build_pipeline`), and the calibration checked against a
recording's frames before any pair is processed (:func:`check_against_frames`)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from cli.console import warn
from cli.errors import fail
from cli.pair_options import load_calibration
from rig.errors import ConfigError

if TYPE_CHECKING:  # the libraries load when an option is used, not for --help
    from rig.capture.recorded import RecordedPairs
    from rig.pipeline import DepthPipeline
    from rig.rectified import RectifiedPairConfig
    from rig.rig_pipeline import RigPipeline
    from rig.stereo import StereoParams

__all__ = [
    "NoCheckOption",
    "StereoOption",
    "build_pipeline",
    "build_pipelines",
    "check_against_frames",
    "describe_pipeline",
    "load_stereo_params",
]

StereoOption = Annotated[
    Path | None, typer.Option("--stereo", metavar="FILE", help="YAML of stereo parameters (ROS names).")
]
NoCheckOption = Annotated[
    bool,
    typer.Option("--no-calibration-check", help="Skip the check of the calibration against the frames."),
]


def load_stereo_params(path: Path) -> StereoParams:
    """StereoParams from a YAML/JSON mapping file; ConfigError naming file and field."""
    import yaml
    from pydantic import ValidationError

    from rig.settings_model import describe_field_errors, field_errors
    from rig.stereo import StereoParams

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


def build_pipeline(
    calibration: Path | None,
    fallback: Path | None,
    config: RectifiedPairConfig,
    stereo: Path | None,
    cache_dir: Path | None,
) -> tuple[DepthPipeline, Path]:
    """The depth pipeline of the options (calibration, rectified pair, stereo file, cache) and the
    calibration file used, with a warning line for each thing the rectified view leaves out (a
    pinhole view leaving a lens's field, a lat-lon field clipped to the lenses' overlap): said
    here once, so the pipeline logs it only at DEBUG."""
    from rig.pipeline import DepthPipeline

    pipeline, cal_path = build_pipelines(calibration, fallback, config, stereo, cache_dir)
    assert isinstance(pipeline, DepthPipeline)  # a rig of more than two cameras was refused
    return pipeline, cal_path


def build_pipelines(
    calibration: Path | None,
    fallback: Path | None,
    config: RectifiedPairConfig,
    stereo: Path | None,
    cache_dir: Path | None,
    *,
    rings: bool = False,
    panorama_px_per_deg: float | None = None,
) -> tuple[DepthPipeline | RigPipeline, Path]:
    """:func:`build_pipeline`, and with ``rings`` for a rig of more than two cameras its
    :class:`~rig.rig_pipeline.RigPipeline` (every pair's warnings said, each naming its pair;
    its panorama at ``panorama_px_per_deg``, default the panorama's own)."""
    from rig.panorama import DEFAULT_PANORAMA_PX_PER_DEG
    from rig.pipeline import DepthPipeline
    from rig.rig_pipeline import RigPipeline

    rig, cal_path = load_calibration(calibration, fallback, rings=rings)
    params = load_stereo_params(stereo) if stereo is not None else None
    if len(rig.names) > 2:
        ring = RigPipeline(
            rig,
            config,
            params,
            cache_dir=cache_dir,
            panorama_px_per_deg=panorama_px_per_deg or DEFAULT_PANORAMA_PX_PER_DEG,
            log_field_warnings=False,
        )
        for label, pipeline in ring.pipelines.items():
            for line in pipeline.in_effect.field_warnings:
                warn(f"{label}: {line}")
        return ring, cal_path
    if panorama_px_per_deg is not None:
        raise ConfigError("--panorama-px-per-deg applies to a rig of more than two cameras (a ring)")
    pipeline = DepthPipeline(rig, config, params, cache_dir=cache_dir, log_field_warnings=False)
    for line in pipeline.in_effect.field_warnings:
        warn(line)
    return pipeline, cal_path


def describe_pipeline(pipeline: DepthPipeline | RigPipeline, cal_path: Path) -> str:
    """One line naming the calibration file, the rectified pair and the baseline (a ring: its
    pairs, its first pair's rectified pair and the panorama)."""
    from rig.rig_pipeline import RigPipeline

    if isinstance(pipeline, RigPipeline):
        return (
            f"calibration {cal_path}, {len(pipeline.rig.names)} cameras, pairs {', '.join(pipeline.labels)} "
            f"({pipeline.first.pair.describe()} first), panorama {pipeline.panorama.camera.width}x"
            f"{pipeline.panorama.camera.height}"
        )
    return f"calibration {cal_path}, {pipeline.pair.describe()}, B {pipeline.baseline_m:.4f} m"


def check_against_frames(pipeline: DepthPipeline | RigPipeline, recording: RecordedPairs) -> None:
    """The calibration against the recording's first readable pair
    (:func:`rig.calibration_check.check_recording`; a ring: every pair, after the recording is
    checked to hold every camera of the calibration): an error stops the command (one line, exit
    status 2), each warning is printed once."""
    from rig.calibration_check import check_recording
    from rig.rig_depth import check_recording_cameras
    from rig.rig_pipeline import RigPipeline

    if isinstance(pipeline, RigPipeline):
        check_recording_cameras(recording, pipeline.cameras)
        pairs = list(pipeline.pipelines.items())
    else:
        pairs = [("", pipeline)]
    findings = [(label, finding) for label, one in pairs for finding in check_recording(one, recording)]
    for label, finding in findings:
        if finding.severity == "error":
            fail(f"{label}: {finding.message}" if label else finding.message)
    for label, finding in findings:
        warn(f"{label}: {finding.message}" if label else finding.message)
