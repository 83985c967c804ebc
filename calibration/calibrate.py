"""Intrinsic calibration of one camera, any model, from no guess.

``calibrate_camera(model, object_points, image_points, image_size)``:

1. views without enough corners are dropped (with the reason);
2. with no ``initial`` guess: equidistant focal length by 1-D search (centre = image centre),
   board poses by PnP on rays (valid past 90° off axis), joint equidistant refinement (robust
   loss), then Kannala-Brandt, a flexible radial lens that every central lens resembles; views
   still far off (bad detections) are dropped;
3. conversion of that lens into the requested model (least squares over the observed field);
4. joint refinement of the model's parameters and all board poses (:mod:`calibration.solver`);
5. with the views' ``images``: fisheye-aware corner refinement (:mod:`calibration.corner_refine`)
   with the lens just found, then the joint refinement again, repeated until the corners move
   less than ``refine_tol_px``. The detector's corners are biased on a fisheye (~0.1 px, pulled
   inwards at the rim); the refined ones are not, which is what lets the lens be recovered to
   ~0.03 px over the whole image circle instead of ~0.5 px.

Shapes: object points (N, 3) per view (board frame), image points (N, 2) per view (NaN rows =
corner not detected), poses 4x4 ``T_cam_board``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.board_views import (
    DroppedView,
    drop_out_of_domain,
    drop_outliers,
    drop_thin_views,
    max_corner_angle,
    prepare_views,
    require_views,
)
from calibration.corner_refine import ImageSource, RefinementReport, refine_views
from calibration.errors import CalibrationError
from calibration.initial_guess import board_poses, convert_model, search_equidistant_focal, seed_model
from calibration.lm import LOSSES
from calibration.models.base import MODELS, CameraModel
from calibration.solver import BundleResult, CameraBlock, Observation, refine_bundle

__all__ = [
    "DEFAULT_FIXED",
    "CameraCalibration",
    "FitOptions",
    "calibrate_camera",
    "check_loss",
    "free_mask",
]

F64 = NDArray[np.float64]

# Parameters held at their initial value (always): Mei's skew (OpenCV's omnidir calibrates it
# only without CALIB_FIX_SKEW; real lenses have none); Scaramuzza's a1, 0 by definition in
# OCamCalib and MATLAB (z(ρ) = a0 + a2 ρ² + ...), and its stretch entry e: A = [[c, d], [e, 1]]
# times a rotation about the optical axis is the same lens seen from a camera turned about that
# axis, which the board poses absorb, so one of d, e is a free gauge (any A equals an
# e = 0 stretch times such a rotation, with the scale taken up by the polynomial).
DEFAULT_FIXED: dict[str, tuple[str, ...]] = {"mei": ("s",), "scaramuzza": ("poly[1]", "e")}


@dataclass(frozen=True)
class FitOptions:
    """How :func:`calibrate_camera` fits a lens (see there for each option); what
    :func:`calibration.stereo_calibrate.calibrate_stereo` passes on to each camera's."""

    fix: tuple[str, ...] = ()
    fov_deg: float | None = None
    loss: str = "linear"
    min_views: int = 3
    refine_rounds: int = 3
    refine_tol_px: float = 1e-3


@dataclass
class CameraCalibration:
    """Result of :func:`calibrate_camera`; per-view lists follow ``views`` (input indices)."""

    camera: CameraModel
    rms: float  # px, over all used corners
    view_rms: F64  # (V,) px
    views: list[int]
    view_names: list[str]
    T_cam_board: list[F64]  # (V,) 4x4
    image_points: list[F64]  # (V,) (N_i, 2) the corners used
    residuals: list[F64]  # (V,) (N_i, 2) projection − detection (px)
    param_std: dict[str, float]  # 1-σ of each free parameter (flat layout names)
    dropped: list[DroppedView] = field(default_factory=list)
    max_angle_deg: float = 0.0  # largest angle of a used corner off the optical axis
    n_corners: int = 0
    converged: bool = True
    message: str = ""
    refinement: RefinementReport | None = None  # None: no images given, detector corners used
    # Input view index -> the corners (N, 2) the final fit used, NaN where not detected or left
    # out by refinement (in input order, unlike ``image_points``).
    corners: dict[int, F64] = field(default_factory=dict)


def free_mask(model: CameraModel, fix: Iterable[str] = ()) -> NDArray[np.bool_]:
    """(P,) mask of the optimised entries of ``model.params``: everything but ``fix`` (names
    as in ``param_layout``, or a list parameter's base name) and the model's default fixes."""
    fixed = set(fix) | set(DEFAULT_FIXED.get(model.name, ()))
    unknown = fixed - set(model.all_param_names()) - set(model.param_layout)
    if unknown:
        raise CalibrationError(f"{model.name}: cannot fix unknown parameter(s) {', '.join(sorted(unknown))}")
    return np.array([n not in fixed and n.split("[")[0] not in fixed for n in model.param_layout])


def calibrate_camera(
    model: str,
    object_points: Sequence[ArrayLike],
    image_points: Sequence[ArrayLike | None],
    image_size: tuple[int, int],
    initial: CameraModel | None = None,
    *,
    fix: Iterable[str] = (),
    fov_deg: float | None = None,
    loss: str = "linear",
    min_views: int = 3,
    view_names: Sequence[str] | None = None,
    images: Sequence[ImageSource | None] | None = None,
    refine_rounds: int = 3,
    refine_tol_px: float = 1e-3,
) -> CameraCalibration:
    """Calibrate a ``model`` camera (a name in ``calibration.models.MODELS``) from board views.

    ``image_size`` is (width, height). ``initial`` (optional, any model) is a starting guess; it
    is not needed. ``fix`` names parameters held at their initial value. ``loss`` is the final
    refinement's loss ("linear" = plain least squares, or "huber"/"soft_l1" with 1 px scale).
    Views that cannot be initialised are dropped and reported in ``result.dropped``; fewer than
    ``min_views`` usable views raise CalibrationFailed.

    ``images`` (one per view: an array, an image file's path, or None) switch on corner
    refinement: at most ``refine_rounds`` rounds of refine → recalibrate, stopping once no
    corner changes by more than ``refine_tol_px``; ``result.refinement`` reports it.
    """
    _check_model_and_loss(model, loss)
    w, h = (int(v) for v in image_size)
    if w <= 0 or h <= 0:
        raise CalibrationError(f"image size must be positive, got {image_size}")
    objs, imgs, names, dropped = prepare_views(object_points, image_points, view_names)
    if images is not None and len(images) != len(objs):
        raise CalibrationError(f"{len(images)} images for {len(objs)} views")
    if refine_rounds < 1 or not refine_tol_px > 0:
        raise CalibrationError("refine_rounds must be >= 1 and refine_tol_px > 0")
    options = FitOptions(tuple(fix), fov_deg, loss, min_views, refine_rounds, refine_tol_px)
    views = [i for i, u in enumerate(imgs) if u is not None]
    require_views(views, min_views, dropped)
    U = {i: u for i, u in enumerate(imgs) if u is not None}
    data = _Views({i: objs[i] for i in views}, U, names, dropped, min_views)

    if initial is None:
        camera, poses, views = _initial_lens(data, views, model, (w, h))
    else:
        camera, poses, views = _poses_for_guess(data, views, initial, (w, h))
    camera, views = _converted(data, camera, poses, views, model, options.fix)
    if fov_deg is not None:
        camera = camera.replace(fov_deg=fov_deg)

    free = free_mask(camera, options.fix)
    final = data.fit(camera, poses, views, free, loss)
    if images is None or all(images[i] is None for i in views):
        return _result(final, views, names, data.X, data.U, dropped)
    return _refine_corners(data, final, views, images, free, options)


def _check_model_and_loss(model: str, loss: str) -> None:
    if model not in MODELS:
        raise CalibrationError(f"unknown camera model {model!r}; known: {', '.join(sorted(MODELS))}")
    check_loss(loss)


def check_loss(loss: str) -> None:
    """``loss`` names a loss of :data:`calibration.lm.LOSSES` (else CalibrationError)."""
    if loss not in LOSSES:
        raise CalibrationError(f"unknown loss {loss!r}; known: {', '.join(LOSSES)}")


@dataclass
class _Views:
    """One camera's board views while it is calibrated: object points ``X`` and detected
    corners ``U`` (NaN rows: not detected) by input index, every view's name, the views
    dropped so far and the fewest views a fit may use."""

    X: dict[int, F64]
    U: dict[int, F64]
    names: list[str]
    dropped: list[DroppedView]
    min_views: int

    def require(self, views: list[int]) -> None:
        require_views(views, self.min_views, self.dropped)

    def seen(self, views: list[int]) -> tuple[list[F64], list[F64]]:
        """The detected corners of ``views`` and their object points."""
        finite = [np.isfinite(self.U[i]).all(axis=1) for i in views]
        return (
            [self.X[i][f] for i, f in zip(views, finite, strict=True)],
            [self.U[i][f] for i, f in zip(views, finite, strict=True)],
        )

    def fit(
        self,
        camera: CameraModel,
        poses: dict[int, F64],
        use: list[int],
        free: NDArray[np.bool_] | None,
        loss: str,
    ) -> BundleResult:
        """The joint refinement of ``camera`` (``free``: its optimised parameters, None: all)
        and the board poses of views ``use``."""
        obs = [Observation(0, k, self.X[i], self.U[i]) for k, i in enumerate(use)]
        return refine_bundle([CameraBlock(camera, free)], [poses[i] for i in use], obs, loss=loss)

    def initial_poses(self, camera: CameraModel, use: list[int]) -> tuple[dict[int, F64], list[int]]:
        """Board poses of views ``use`` by PnP on rays; views no pose fits are dropped.
        Returns the poses and the views left."""
        found = board_poses(camera, *self.seen(use))
        poses = {}
        for i, T in zip(use, found, strict=True):
            if T is None:
                self.dropped.append(DroppedView(i, self.names[i], "no board pose fits the corners"))
            else:
                poses[i] = T
        return poses, [i for i in use if i in poses]


def _initial_lens(
    data: _Views, views: list[int], model: str, size: tuple[int, int]
) -> tuple[CameraModel, dict[int, F64], list[int]]:
    """A lens from no guess: the equidistant focal length by 1-D search, board poses by PnP on
    rays, a robust equidistant fit, then (for any other ``model``) a Kannala-Brandt one; views
    far off after a fit are dropped. Returns the lens, the poses and the views left."""
    camera: CameraModel = search_equidistant_focal(*data.seen(views), size)
    poses, views = data.initial_poses(camera, views)
    data.require(views)
    stage = data.fit(camera, poses, views, None, "soft_l1")
    views, poses = drop_outliers(stage, views, data.names, data.dropped, data.min_views)
    camera = stage.cameras[0]
    if model != "equidistant":
        kb = seed_model("kannala_brandt", camera, math.pi)
        stage = data.fit(kb, poses, views, None, "soft_l1")
        views, poses = drop_outliers(stage, views, data.names, data.dropped, data.min_views)
        camera = stage.cameras[0]
    return camera, poses, views


def _poses_for_guess(
    data: _Views, views: list[int], initial: CameraModel, size: tuple[int, int]
) -> tuple[CameraModel, dict[int, F64], list[int]]:
    """The ``initial`` lens (checked against the image ``size``), the board poses it gives and
    the views left."""
    w, h = size
    if (initial.width, initial.height) != (w, h):
        raise CalibrationError(
            f"initial guess is for {initial.width}x{initial.height} images, the views are {w}x{h}"
        )
    poses, views = data.initial_poses(initial, views)
    data.require(views)
    return initial, poses, views


def _converted(
    data: _Views,
    camera: CameraModel,
    poses: dict[int, F64],
    views: list[int],
    model: str,
    fix: tuple[str, ...],
) -> tuple[CameraModel, list[int]]:
    """``camera``'s lens as a ``model`` lens (least squares over the observed field) and the
    views left: those with corners the model cannot image are dropped."""
    if camera.name == model:
        return camera, views
    theta_obs = max_corner_angle(poses, data.X, views)
    target = seed_model(model, camera, theta_obs)
    limit = min(theta_obs * 1.02, 0.98 * target.max_theta)
    camera = convert_model(camera, target, limit, free_mask(target, fix))
    views = drop_out_of_domain(camera, poses, data.X, data.U, views, data.names, data.dropped)
    data.require(views)
    return camera, views


def _refine_corners(
    data: _Views,
    final: BundleResult,
    views: list[int],
    images: Sequence[ImageSource | None],
    free: NDArray[np.bool_],
    options: FitOptions,
) -> CameraCalibration:
    """Corner refinement with the lens just found (``final``), then the joint refinement
    again, for at most ``options.refine_rounds`` rounds, until no corner moves by more than
    ``options.refine_tol_px``; the calibration with its :class:`RefinementReport`."""
    U = data.U
    raw = {i: U[i] for i in views}
    rms_before, changes, previous = final.rms, [], raw
    for _ in range(options.refine_rounds):
        refined, rejected = refine_views(
            images, {i: raw[i] for i in views}, final.cameras[0], data.X, data.names
        )
        changes.append(_largest_change(refined, previous))  # over the views still in use
        U.update(refined)
        poses = dict(zip(views, final.T_ref_board, strict=True))
        kept = drop_thin_views(U, views, data.names, data.dropped)
        data.require(kept)
        if kept != views:
            views, poses = kept, {i: poses[i] for i in kept}
        final = data.fit(final.cameras[0], poses, views, free, options.loss)
        previous = refined
        if changes[-1] <= options.refine_tol_px:
            break
    shifts = np.concatenate([np.linalg.norm(U[i] - raw[i], axis=1) for i in views])
    report = RefinementReport(
        rms_before=rms_before,
        rms_after=final.rms,
        rounds=len(changes),
        changes_px=tuple(changes),
        converged=changes[-1] <= options.refine_tol_px,
        mean_shift_px=float(np.nanmean(shifts)) if np.isfinite(shifts).any() else 0.0,
        n_corners=int(sum(int(k.sum()) for k in final.kept)),
        rejected=tuple(r for r in rejected if r.view in views),
    )
    return _result(final, views, data.names, data.X, U, dropped=data.dropped, refinement=report)


def _largest_change(refined: dict[int, F64], previous: dict[int, F64]) -> float:
    """Largest distance (px) between the corners of two rounds, over corners found in both."""
    d = np.concatenate([np.linalg.norm(refined[i] - previous[i], axis=1) for i in refined])
    return float(np.nanmax(d)) if np.isfinite(d).any() else 0.0


def _result(
    final: BundleResult,
    views: list[int],
    names: list[str],
    X: dict[int, F64],
    U: dict[int, F64],
    dropped: list[DroppedView],
    refinement: RefinementReport | None = None,
) -> CameraCalibration:
    camera = final.cameras[0]
    std = final.param_std[0]
    layout = camera.param_layout
    angles = [
        max_corner_angle({i: final.T_ref_board[k]}, {i: X[i][final.kept[k]]}, [i])
        for k, i in enumerate(views)
    ]
    view_rms = np.array([np.sqrt(np.mean(np.sum(r**2, axis=1))) for r in final.residuals])
    return CameraCalibration(
        camera=camera,
        rms=final.rms,
        view_rms=view_rms,
        views=list(views),
        view_names=[names[i] for i in views],
        T_cam_board=list(final.T_ref_board),
        image_points=[U[i][final.kept[k]] for k, i in enumerate(views)],
        residuals=list(final.residuals),
        param_std={n: float(s) for n, s in zip(layout, std, strict=True) if np.isfinite(s)},
        dropped=sorted(dropped, key=lambda d: d.index),
        max_angle_deg=float(np.degrees(max(angles))) if angles else 0.0,
        n_corners=int(sum(len(r) for r in final.residuals)),
        converged=final.success,
        message=final.message,
        refinement=refinement,
        corners={i: U[i] for i in views},
    )
