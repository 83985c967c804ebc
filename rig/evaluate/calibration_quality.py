"""Calibration quality (the paper's Table I): chessboards rendered through the preset's true lens,
corners found by the project's detector (``cv2.findChessboardCornersSB`` via
:func:`calibration.targets.detect_chessboard`, not the renderer's exact corners), every model
calibrated from no guess on the same detections and images — with the project's fisheye-aware
corner refinement (``calibrate_camera(images=...)``: the detector's corners are biased on a
fisheye, the refined ones are not) unless the config turns it off.

The corners are also compared with the renderer's exact corner positions: the detector's RMS
error, and per model the RMS error of the (refined) corners its final fit used.

Each distinct lens of the rig is calibrated (paper-sim: one lens shared by both cameras, as in
the paper; prototype: left and right differ). A model that fails to calibrate is recorded with
the reason and the run goes on without it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from calibration.calibrate import CameraCalibration, calibrate_camera
from calibration.errors import CalibrationError
from calibration.models import CameraModel
from calibration.rig import Rig
from calibration.targets import board_object_points, detect_chessboard
from rig.evaluate.config import EvalConfig
from rig.evaluate.renders import calibration_board_poses, render_board
from rig.sim.lens_effects import LensEffects

__all__ = ["BoardViews", "CalibrationStudy", "ModelCalibration", "distinct_lenses", "run_calibration_study"]

F64 = NDArray[np.float64]

#: ``step(description)`` after each unit of work (a rendered view, a calibrated model).
Step = Callable[[str], None]


@dataclass
class BoardViews:
    """Rendered board views of one lens and what the detector found in them."""

    lens: CameraModel
    poses: list[F64]  # T_cam_board per rendered view
    images: list[NDArray[np.uint8]]  # the rendered views (H, W)
    corners: list[F64 | None]  # detections (N, 2) or None
    exact: list[F64]  # the true corner pixels (N, 2) per view
    detector_rms_px: float  # detections against the exact corners
    max_angle_deg: float  # largest angle off axis of a detected corner (true geometry)

    @property
    def n_detected(self) -> int:
        return sum(c is not None for c in self.corners)


@dataclass
class ModelCalibration:
    """One model on every distinct lens: ``results[lens_name]`` or the failure reason."""

    model: str
    results: dict[str, CameraCalibration] = field(default_factory=dict)
    corner_rms_px: dict[str, float] = field(default_factory=dict)  # per lens: used corners vs truth
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None

    @property
    def converged(self) -> bool:
        """False when the final refinement stopped before its convergence test (the result is
        still used, and the table says so)."""
        return self.ok and all(r.converged for r in self.results.values())

    def camera_for(self, study: CalibrationStudy, name: str) -> CameraModel:
        return self.results[study.lens_of[name]].camera


@dataclass
class CalibrationStudy:
    """``lens_of[camera] -> lens name`` (the camera that was calibrated for it), the views per
    lens and one :class:`ModelCalibration` per model (in the configured order)."""

    lens_of: dict[str, str]
    views: dict[str, BoardViews]
    models: dict[str, ModelCalibration]

    def calibrated_rig(self, rig: Rig, model: str) -> Rig:
        """``rig`` with every camera replaced by its calibrated ``model`` (true extrinsics)."""
        m = self.models[model]
        return Rig(
            {n: m.camera_for(self, n) for n in rig.names}, {n: T.copy() for n, T in rig.T_rig_cam.items()}
        )


def distinct_lenses(rig: Rig) -> dict[str, str]:
    """Camera name -> the first camera with the same lens (identical model and parameters)."""
    out: dict[str, str] = {}
    for name in rig.names:
        same = [o for o in out.values() if rig.cameras[o].to_dict() == rig.cameras[name].to_dict()]
        out[name] = same[0] if same else name
    return out


def _views(
    lens: CameraModel,
    config: EvalConfig,
    rng: np.random.Generator,
    step: Step,
    effects: LensEffects | None,
    camera_index: int,
) -> BoardViews:
    poses = calibration_board_poses(lens, config.calibration_views, rng, config.board, config.square_m)
    X = board_object_points(*config.board, config.square_m)
    images: list[NDArray[np.uint8]] = []
    corners: list[F64 | None] = []
    exact: list[F64] = []
    top = 0.0
    for i, T in enumerate(poses):
        image = render_board(
            lens, T, config.board, config.square_m, config.supersample, effects=effects,
            camera_index=camera_index, seed=config.seed * 1000 + i,
        )  # fmt: skip
        found = detect_chessboard(image, config.board)
        images.append(image)
        corners.append(found)
        p = X @ T[:3, :3].T + T[:3, 3]
        exact.append(lens.project(p, in_image=False)[0])
        if found is not None:
            top = max(
                top, float(np.degrees(np.arccos(np.clip(p[:, 2] / np.linalg.norm(p, axis=1), -1, 1))).max())
            )
        step("rendering and detecting calibration boards")
    return BoardViews(lens, poses, images, corners, exact, _corner_rms(corners, exact), top)


def _corner_rms(corners: Sequence[F64 | None], exact: Sequence[F64]) -> float:
    """RMS distance (px) of the found corners (NaN rows skipped) from the exact ones."""
    d = [np.linalg.norm(c - e, axis=1) for c, e in zip(corners, exact, strict=True) if c is not None]
    dd = np.concatenate(d) if d else np.zeros(0)
    dd = dd[np.isfinite(dd)]
    return float(np.sqrt(np.mean(dd**2))) if dd.size else math.nan


def run_calibration_study(
    rig: Rig, config: EvalConfig, models: Sequence[str], step: Step, effects: LensEffects | None = None
) -> CalibrationStudy:
    """Render (through the lens ``effects``, None: ideal), detect and calibrate (see the module
    doc). Never raises for a model that cannot be calibrated: its :class:`ModelCalibration`
    carries the reason."""
    lens_of = distinct_lenses(rig)
    lenses = list(dict.fromkeys(lens_of.values()))
    rng = np.random.default_rng([config.seed, 11])
    index = {name: i for i, name in enumerate(rig.cameras)}
    views = {name: _views(rig.cameras[name], config, rng, step, effects, index[name]) for name in lenses}
    X = board_object_points(*config.board, config.square_m)
    out: dict[str, ModelCalibration] = {}
    for model in models:
        mc = ModelCalibration(model)
        for name in lenses:
            bv = views[name]
            lens = bv.lens
            try:
                res = calibrate_camera(
                    model, [X] * len(bv.corners), bv.corners, (lens.width, lens.height),
                    fov_deg=lens.fov_deg, view_names=[f"{name} view {i}" for i in range(len(bv.corners))],
                    images=bv.images if config.refine_corners else None, refine_rounds=config.refine_rounds,
                )  # fmt: skip
            except CalibrationError as err:
                mc.error = f"{name}: {err}"
                mc.results.clear()
                break
            mc.results[name] = res
            used = [res.corners.get(i) if res.corners else bv.corners[i] for i in range(len(bv.corners))]
            mc.corner_rms_px[name] = _corner_rms(used, bv.exact)
            step(f"calibrating {model}")
        out[model] = mc
    return CalibrationStudy(lens_of, views, out)
