"""The extrinsics chain a user really has (docs/rectification.md): the relative pose calibrated
from rendered chessboards in the overlap wedge (what ``rig calibrate stereo`` does, with the
lenses of the calibration study held fixed), then refined from the scene of a short room
recording (what ``rig calibrate refine`` does). The depth study measures the study's
``extrinsics_model`` with three extrinsics: the true ones (its usual curve), the calibrated and
the refined ones (curves :data:`CALIBRATED` and :data:`REFINED`).

Boards: poses ahead of the rig (its z axis), tilted and spun, kept where the whole board with
half a square of margin is inside both lenses' fields; at ``max(0.45 m, 4 baselines)``.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from calibration.errors import CalibrationError
from calibration.geometry import invert_transform, rotation_angle
from calibration.models import CameraModel
from calibration.rig import Rig
from calibration.stereo_calibrate import calibrate_stereo
from calibration.targets import board_object_points, detect_chessboard
from rig.errors import RigError
from rig.evaluate.calibration_quality import CalibrationStudy
from rig.evaluate.config import EvalConfig
from rig.evaluate.renders import board_fits, board_outline, board_pose, render_board
from rig.recording import Recording
from rig.rectification import RectificationRefinement, RefineOptions, refine_recording
from rig.rectified import RectifiedPairConfig
from rig.sim.presets import Preset
from rig.sim.simulate import simulate_recording

__all__ = [
    "CALIBRATED",
    "REFINED",
    "ExtrinsicsStudy",
    "PoseError",
    "pose_error",
    "run_extrinsics_study",
    "steps",
]

F64 = NDArray[np.float64]
Step = Callable[[str], None]

CALIBRATED = "calibrated_extrinsics"
REFINED = "refined_extrinsics"
# Candidate board directions in the rig frame: (theta, phi, tilt, spin) in degrees.
_WEDGE = [
    (0, 0, (0, 0), 0), (20, 0, (15, 0), 10), (20, 180, (0, 15), -10), (25, 90, (0, -20), 20),
    (25, 270, (20, 0), 30), (30, 30, (0, 0), -20), (30, 150, (0, 0), 15), (15, 220, (-15, 10), 5),
    (35, 0, (0, 30), 0), (35, 180, (0, -30), 0), (10, 45, (30, 0), 45), (10, 135, (-30, 0), -45),
    (30, 300, (20, 20), 0), (30, 240, (-20, 20), 0), (40, 10, (0, 0), 90), (40, 170, (0, 0), -90),
]  # fmt: skip
_RIM_CLEARANCE_DEG = 0.5
# Ground truth of the room recording is not used: the smallest VPC keeps its render cheap.
_GT_VPC = RectifiedPairConfig(width=32, height=24)


@dataclass(frozen=True)
class PoseError:
    """A relative pose against the truth: rotation (deg), translation (mm), baseline length (mm)."""

    rotation_deg: float
    translation_mm: float
    baseline_mm: float


def pose_error(rig: Rig, truth: Rig, left: str = "left", right: str = "right") -> PoseError:
    def rel(r: Rig) -> F64:
        return invert_transform(r.T_rig_cam[right]) @ r.T_rig_cam[left]

    T, T0 = rel(rig), rel(truth)
    return PoseError(
        math.degrees(rotation_angle(T[:3, :3] @ T0[:3, :3].T)),
        1e3 * float(np.linalg.norm(T[:3, 3] - T0[:3, 3])),
        1e3 * (rig.baseline(left, right) - truth.baseline(left, right)),
    )


@dataclass
class ExtrinsicsStudy:
    """What the chain found (``error`` when a step failed; the curves are then left out)."""

    model: str
    board_views: int = 0
    common_views: int = 0
    stereo_rms_px: float = math.nan
    calibrated: PoseError | None = None
    calibrated_sigma_deg: float = math.nan
    refined: PoseError | None = None
    refinement: RectificationRefinement | None = None
    rigs: dict[str, Rig] | None = None
    error: str | None = None


def _wedge_poses(rig: Rig, config: EvalConfig) -> list[F64]:
    """``T_rig_board`` of the wedge boards both lenses see whole."""
    distance = max(0.45, 4.0 * rig.baseline())
    outline = board_outline(config.board, config.square_m, 0.5)
    out = []
    for theta, phi, tilt, spin in _WEDGE:
        T = board_pose(config.board, config.square_m, theta, phi, distance, tilt, spin)
        fits = all(
            board_fits(
                rig.cameras[n],
                invert_transform(rig.T_rig_cam[n]) @ T,
                outline,
                math.degrees(rig.cameras[n].max_theta) - _RIM_CLEARANCE_DEG,
            )
            for n in ("left", "right")
        )
        if fits:
            out.append(T)
    return out[: config.stereo_views]


def _calibrate(
    preset: Preset, lenses: dict[str, CameraModel], config: EvalConfig, step: Step, study: ExtrinsicsStudy
) -> Rig:
    truth = preset.rig
    poses = _wedge_poses(truth, config)
    study.board_views = len(poses)
    images: dict[str, list[NDArray[np.uint8] | None]] = {"left": [], "right": []}
    corners: dict[str, list[F64 | None]] = {"left": [], "right": []}
    for k, T in enumerate(poses):
        for i, name in enumerate(("left", "right")):
            T_cam_board = invert_transform(truth.T_rig_cam[name]) @ T
            image = render_board(
                truth.cameras[name], T_cam_board, config.board, config.square_m, config.supersample,
                effects=config.lens_effects(preset), camera_index=list(truth.cameras).index(name),
                seed=config.seed * 1000 + 2 * k + i,
            )  # fmt: skip
            images[name].append(image)
            corners[name].append(detect_chessboard(image, config.board))
        step("rendering stereo calibration boards")
    X = board_object_points(*config.board, config.square_m)
    lens_l = truth.cameras["left"]
    result = calibrate_stereo(
        study.model, [X] * len(poses), corners["left"], corners["right"], (lens_l.width, lens_l.height),
        right_image_size=(truth.cameras["right"].width, truth.cameras["right"].height),
        left_initial=lenses["left"], right_initial=lenses["right"], fix_intrinsics=True,
        left_images=images["left"], right_images=images["right"], refine_rounds=config.refine_rounds,
    )  # fmt: skip
    study.common_views = len(result.common_views)
    study.stereo_rms_px = result.rms
    study.calibrated_sigma_deg = result.rotation_std_deg
    step("calibrating the pair")
    return result.rig


def run_extrinsics_study(
    preset: Preset, study: CalibrationStudy, config: EvalConfig, step: Step
) -> ExtrinsicsStudy:
    """Calibrate the pair from boards, refine it from the room (see the module doc); never
    raises for a step that fails: the result carries the reason."""
    truth = preset.rig
    out = ExtrinsicsStudy(config.extrinsics_model)
    mc = study.models.get(config.extrinsics_model)
    if mc is None or not mc.ok:
        out.error = f"{config.extrinsics_model} was not calibrated" + (
            f" ({mc.error})" if mc and mc.error else ""
        )
        return out
    lenses = {n: mc.camera_for(study, n) for n in ("left", "right")}
    try:
        calibrated = _calibrate(preset, lenses, config, step, out)
        out.calibrated = pose_error(calibrated, truth)
        with tempfile.TemporaryDirectory(prefix="rig-evaluate-room-") as tmp:
            root = simulate_recording(
                preset, "room", Path(tmp) / "room", frames=config.refine_frames, seed=config.seed,
                supersample=config.supersample, vpc=_GT_VPC, lens=config.lens,
            )  # fmt: skip
            step("rendering the room")
            refinement = refine_recording(Recording(root), calibrated, config.vpc, RefineOptions())
            step("refining the extrinsics from the room")
    except (CalibrationError, RigError) as err:
        out.error = str(err)
        return out
    out.refinement = refinement
    out.refined = pose_error(refinement.rig_after, truth)
    out.rigs = {CALIBRATED: calibrated, REFINED: refinement.rig_after}
    return out


def steps(config: EvalConfig) -> int:
    """Progress steps of :func:`run_extrinsics_study` (board renders, calibration, room, refinement)."""
    return config.stereo_views + 3
