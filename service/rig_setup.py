"""What the service checks and builds from its settings before anything runs: the calibration
file (:func:`resolve_calibration`), a two-camera rig's cameras against the capture's, a rig of N
cameras' pipeline (:func:`ring_pipeline`: its cameras configured, its memory budget fitting) and
the cameras' frame sizes against the calibration's (:func:`check_sizes`)."""

from __future__ import annotations

from pathlib import Path

from calibration.rig import Rig
from rig.capture.capture import CAMERA_NAMES, RigCapture
from rig.capture.config import CaptureConfig, FileCameraConfig
from rig.panorama import PanoramaSpec
from rig.rectified import design_rectified_pair
from rig.rig_pipeline import RigPipeline, pair_config
from rig.ring import stereo_pairs
from service.errors import SettingsError
from service.memory import check_memory, ring_estimate
from service.settings import Settings

__all__ = ["check_sizes", "check_two_cameras", "resolve_calibration", "ring_pipeline"]


def resolve_calibration(settings: Settings) -> Path:
    """``calibration.path``, else the ``calibration.yaml`` of the recording both file cameras
    replay; SettingsError naming the field otherwise."""
    if settings.calibration.path is not None:
        return settings.calibration.path
    cams = settings.cameras
    if cams is not None:
        configs = [cams.camera(n) for n in cams.names]
        files = [c for c in configs if isinstance(c, FileCameraConfig)]
        if len(files) == len(configs) and len({c.recording for c in files}) == 1:
            candidate = files[0].recording / "calibration.yaml"
            if candidate.is_file():
                return candidate
    raise SettingsError(
        "settings: field 'calibration.path': not set, and the cameras replay no recording with a "
        "calibration.yaml"
    )


def check_two_cameras(settings: Settings, rig: Rig, calibration: Path) -> None:
    """A two-camera calibration needs ``left`` and ``right``, captured as such, and has no
    panorama to configure."""
    cams = settings.cameras
    assert cams is not None
    if "panorama" in settings.model_fields_set:
        raise SettingsError(
            f"settings: field 'panorama': the calibration {calibration} is a two-camera rig: a panorama is "
            "fused only on a rig of more than two cameras"
        )
    for name in CAMERA_NAMES:
        if name not in rig.cameras:
            raise SettingsError(f"{calibration}: the rig has no camera {name!r} (has {', '.join(rig.names)})")
    if cams.rig is not None:
        raise SettingsError(
            f"settings: field 'cameras.rig': the calibration {calibration} is a two-camera rig (left, "
            "right): configure cameras.left and cameras.right"
        )


def ring_pipeline(settings: Settings, rig: Rig, calibration: Path) -> RigPipeline:
    """The pipeline of a rig of more than two cameras, after its cameras are checked against the
    capture's and its memory budget against the machine's."""
    cams = settings.cameras
    assert cams is not None
    stereo = settings.stereo
    missing = [n for n in rig.names if n not in cams.names]
    if missing:
        raise SettingsError(
            f"settings: field 'cameras': the calibration {calibration} has cameras {', '.join(rig.names)}; "
            f"{', '.join(missing)} not configured (a rig of N cameras is configured as cameras.rig)"
        )
    pairs = [
        design_rectified_pair(rig, pair_config(settings.rectified, names), blind_band_px=stereo.blind_band_px)
        for names in stereo_pairs(rig)
    ]
    if not pairs:
        raise SettingsError(
            f"{calibration}: no two of the rig's cameras see a common direction: no stereo pair"
        )
    px_per_deg = settings.panorama.px_per_deg
    panorama = PanoramaSpec.for_rig(rig, px_per_deg).camera
    check_memory(
        ring_estimate(settings, rig, pairs, stereo, (panorama.width, panorama.height)), pairs[0], stereo
    )
    return RigPipeline(
        rig, settings.rectified, stereo, cache_dir=settings.cache_dir, panorama_px_per_deg=px_per_deg
    )


def check_sizes(settings_cams: CaptureConfig, capture: RigCapture, rig: Rig) -> None:
    """Frames of another size than the calibration's would give wrong depth: refuse at start."""
    for name in capture.names:
        info = capture.camera(name).info()
        model = rig.cameras[name]
        if info.width and info.height and (info.width, info.height) != (model.width, model.height):
            source = "recording" if isinstance(settings_cams.camera(name), FileCameraConfig) else "config"
            raise SettingsError(
                f"settings: field 'cameras.{name}': the camera's {source} gives {info.width}x{info.height} "
                f"frames but its calibration is {model.width}x{model.height}"
            )
