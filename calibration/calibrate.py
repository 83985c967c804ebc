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

from calibration.corner_refine import ImageSource, RefinementReport, refine_views
from calibration.errors import CalibrationError, CalibrationFailed
from calibration.initial_guess import board_poses, convert_model, search_equidistant_focal, seed_model
from calibration.lm import LOSSES
from calibration.models.base import MODELS, CameraModel
from calibration.solver import BundleResult, CameraBlock, Observation, refine_bundle

__all__ = [
    "DEFAULT_FIXED",
    "CameraCalibration",
    "DroppedView",
    "calibrate_camera",
    "free_mask",
    "prepare_views",
]

F64 = NDArray[np.float64]

# Parameters held at their initial value (always): Mei's skew (OpenCV's omnidir calibrates it
# only without CALIB_FIX_SKEW; real lenses have none); Scaramuzza's a1, 0 by definition in
# OCamCalib and MATLAB (z(ρ) = a0 + a2 ρ² + ...), and its stretch entry e: A = [[c, d], [e, 1]]
# times a rotation about the optical axis is the same lens seen from a camera turned about that
# axis, which the board poses absorb, so one of d, e is a free gauge (any A equals an
# e = 0 stretch times such a rotation, with the scale taken up by the polynomial).
DEFAULT_FIXED: dict[str, tuple[str, ...]] = {"mei": ("s",), "scaramuzza": ("poly[1]", "e")}

# Minimum corners for a view to give a pose.
MIN_CORNERS = 6

# A view is an outlier during initialisation when its RMS exceeds both of these.
_OUTLIER_FACTOR = 8.0
_OUTLIER_MIN_PX = 2.0


@dataclass(frozen=True)
class DroppedView:
    """A view left out of the calibration: its input index, name and why."""

    index: int
    name: str
    reason: str


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


def prepare_views(
    object_points: Sequence[ArrayLike],
    image_points: Sequence[ArrayLike | None],
    names: Sequence[str] | None,
) -> tuple[list[F64], list[F64 | None], list[str], list[DroppedView]]:
    """Validate per-view arrays; views with fewer than MIN_CORNERS detected corners become
    DroppedView. Returns object points, image points (None for dropped), names, dropped."""
    if len(object_points) != len(image_points):
        raise CalibrationError(
            f"{len(object_points)} object point sets but {len(image_points)} image point sets"
        )
    names = list(names) if names is not None else [f"view {i}" for i in range(len(object_points))]
    if len(names) != len(object_points):
        raise CalibrationError(f"{len(names)} view names for {len(object_points)} views")
    objs: list[F64] = []
    imgs: list[F64 | None] = []
    dropped: list[DroppedView] = []
    for i, (X, u) in enumerate(zip(object_points, image_points, strict=True)):
        Xa = np.asarray(X, dtype=np.float64).reshape(-1, 3)
        objs.append(Xa)
        if u is None:
            imgs.append(None)
            dropped.append(DroppedView(i, names[i], "no corners detected"))
            continue
        ua = np.asarray(u, dtype=np.float64).reshape(-1, 2)
        if len(ua) != len(Xa):
            raise CalibrationError(f"{names[i]}: {len(ua)} image points but {len(Xa)} object points")
        if not np.isfinite(Xa).all():
            raise CalibrationError(f"{names[i]}: object points must be finite")
        n = int(np.isfinite(ua).all(axis=1).sum())
        if n < MIN_CORNERS:
            imgs.append(None)
            dropped.append(DroppedView(i, names[i], f"only {n} corners (need {MIN_CORNERS})"))
            continue
        imgs.append(ua)
    return objs, imgs, names, dropped


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
    if model not in MODELS:
        raise CalibrationError(f"unknown camera model {model!r}; known: {', '.join(sorted(MODELS))}")
    if loss not in LOSSES:
        raise CalibrationError(f"unknown loss {loss!r}; known: {', '.join(LOSSES)}")
    w, h = (int(v) for v in image_size)
    if w <= 0 or h <= 0:
        raise CalibrationError(f"image size must be positive, got {image_size}")
    objs, imgs, names, dropped = prepare_views(object_points, image_points, view_names)
    if images is not None and len(images) != len(objs):
        raise CalibrationError(f"{len(images)} images for {len(objs)} views")
    if refine_rounds < 1 or not refine_tol_px > 0:
        raise CalibrationError("refine_rounds must be >= 1 and refine_tol_px > 0")
    views = [i for i, u in enumerate(imgs) if u is not None]
    _require(views, min_views, dropped)

    X = {i: objs[i] for i in views}
    U: dict[int, F64] = {i: u for i, u in enumerate(imgs) if u is not None}

    def fit(camera: CameraModel, poses: dict[int, F64], use: list[int], free: NDArray[np.bool_] | None,
            loss_: str) -> BundleResult:  # fmt: skip
        obs = [Observation(0, k, X[i], U[i]) for k, i in enumerate(use)]
        return refine_bundle([CameraBlock(camera, free)], [poses[i] for i in use], obs, loss=loss_)

    def initial_poses(camera: CameraModel, use: list[int]) -> tuple[dict[int, F64], list[int]]:
        finite = [np.isfinite(U[i]).all(axis=1) for i in use]
        found = board_poses(camera, [X[i][f] for i, f in zip(use, finite, strict=True)],
                            [U[i][f] for i, f in zip(use, finite, strict=True)])  # fmt: skip
        poses = {}
        for i, T in zip(use, found, strict=True):
            if T is None:
                dropped.append(DroppedView(i, names[i], "no board pose fits the corners"))
            else:
                poses[i] = T
        return poses, [i for i in use if i in poses]

    if initial is None:
        finite = [np.isfinite(U[i]).all(axis=1) for i in views]
        camera: CameraModel = search_equidistant_focal(
            [X[i][f] for i, f in zip(views, finite, strict=True)],
            [U[i][f] for i, f in zip(views, finite, strict=True)],
            (w, h),
        )
        poses, views = initial_poses(camera, views)
        _require(views, min_views, dropped)
        stage = fit(camera, poses, views, None, "soft_l1")
        views, poses = _drop_outliers(stage, views, names, dropped, min_views)
        camera = stage.cameras[0]
        if model != "equidistant":
            kb = seed_model("kannala_brandt", camera, math.pi)
            stage = fit(kb, poses, views, None, "soft_l1")
            views, poses = _drop_outliers(stage, views, names, dropped, min_views)
            camera = stage.cameras[0]
    else:
        if (initial.width, initial.height) != (w, h):
            raise CalibrationError(
                f"initial guess is for {initial.width}x{initial.height} images, the views are {w}x{h}"
            )
        camera = initial
        poses, views = initial_poses(camera, views)
        _require(views, min_views, dropped)

    if camera.name != model:
        theta_obs = _max_angle(poses, X, views)
        target = seed_model(model, camera, theta_obs)
        limit = min(theta_obs * 1.02, 0.98 * target.max_theta)
        camera = convert_model(camera, target, limit, free_mask(target, fix))
        views = _drop_out_of_domain(camera, poses, X, U, views, names, dropped)
        _require(views, min_views, dropped)
    if fov_deg is not None:
        camera = camera.replace(fov_deg=fov_deg)

    final = fit(camera, poses, views, free_mask(camera, fix), loss)
    if images is None or all(images[i] is None for i in views):
        return _result(final, views, names, X, U, dropped)

    # ---- corner refinement with the lens just found ------------------------------------------
    raw = {i: U[i] for i in views}
    rms_before, changes, previous = final.rms, [], raw
    for _ in range(refine_rounds):
        refined, rejected = refine_views(images, {i: raw[i] for i in views}, final.cameras[0], X, names)
        changes.append(_largest_change(refined, previous))  # over the views still in use
        U.update(refined)
        poses = dict(zip(views, final.T_ref_board, strict=True))
        kept = _drop_thin_views(U, views, names, dropped)
        _require(kept, min_views, dropped)
        if kept != views:
            views, poses = kept, {i: poses[i] for i in kept}
        final = fit(final.cameras[0], poses, views, free_mask(camera, fix), loss)
        previous = refined
        if changes[-1] <= refine_tol_px:
            break
    shifts = np.concatenate([np.linalg.norm(U[i] - raw[i], axis=1) for i in views])
    report = RefinementReport(
        rms_before=rms_before,
        rms_after=final.rms,
        rounds=len(changes),
        changes_px=tuple(changes),
        converged=changes[-1] <= refine_tol_px,
        mean_shift_px=float(np.nanmean(shifts)) if np.isfinite(shifts).any() else 0.0,
        n_corners=int(sum(int(k.sum()) for k in final.kept)),
        rejected=tuple(r for r in rejected if r.view in views),
    )
    return _result(final, views, names, X, U, dropped, report)


def _largest_change(refined: dict[int, F64], previous: dict[int, F64]) -> float:
    """Largest distance (px) between the corners of two rounds, over corners found in both."""
    d = np.concatenate([np.linalg.norm(refined[i] - previous[i], axis=1) for i in refined])
    return float(np.nanmax(d)) if np.isfinite(d).any() else 0.0


def _drop_thin_views(
    U: dict[int, F64], views: list[int], names: list[str], dropped: list[DroppedView]
) -> list[int]:
    """Views left with fewer than MIN_CORNERS corners after refinement are dropped."""
    keep = []
    for i in views:
        n = int(np.isfinite(U[i]).all(axis=1).sum())
        if n >= MIN_CORNERS:
            keep.append(i)
        else:
            dropped.append(DroppedView(i, names[i], f"only {n} corners left after corner refinement"))
    return keep


def _require(views: list[int], min_views: int, dropped: list[DroppedView]) -> None:
    if len(views) >= min_views:
        return
    reasons = "; ".join(f"{d.name}: {d.reason}" for d in dropped[:5])
    more = f" (+{len(dropped) - 5} more)" if len(dropped) > 5 else ""
    raise CalibrationFailed(
        f"only {len(views)} usable view(s), need at least {min_views}"
        + (f" — {reasons}{more}" if reasons else "")
    )


def _drop_outliers(
    stage: BundleResult, views: list[int], names: list[str], dropped: list[DroppedView], min_views: int
) -> tuple[list[int], dict[int, F64]]:
    """Drop views whose RMS is far above the others' after an initialisation stage."""
    rms = np.array([np.sqrt(np.mean(np.sum(r**2, axis=1))) for r in stage.residuals])
    limit = max(_OUTLIER_FACTOR * float(np.median(rms)), _OUTLIER_MIN_PX)
    keep = []
    for k, i in enumerate(views):
        if rms[k] > limit:
            dropped.append(DroppedView(i, names[i], f"reprojection {rms[k]:.1f} px, far above the others"))
        else:
            keep.append(k)
    _require([views[k] for k in keep], min_views, dropped)
    return [views[k] for k in keep], {views[k]: stage.T_ref_board[k] for k in keep}


def _max_angle(poses: dict[int, F64], X: dict[int, F64], views: list[int]) -> float:
    """Largest angle (rad) of a board corner off the optical axis over the views."""
    best = 0.0
    for i in views:
        p = X[i] @ poses[i][:3, :3].T + poses[i][:3, 3]
        cos = p[:, 2] / np.linalg.norm(p, axis=1)
        best = max(best, float(np.arccos(np.clip(cos, -1.0, 1.0)).max()))
    return best


def _drop_out_of_domain(
    camera: CameraModel,
    poses: dict[int, F64],
    X: dict[int, F64],
    U: dict[int, F64],
    views: list[int],
    names: list[str],
    dropped: list[DroppedView],
) -> list[int]:
    """Views with corners the model cannot image (e.g. past 90° for a pinhole) are dropped."""
    keep = []
    for i in views:
        seen = np.isfinite(U[i]).all(axis=1)
        p = X[i][seen] @ poses[i][:3, :3].T + poses[i][:3, 3]
        _, ok = camera.project(p, in_image=False)
        if ok.all():
            keep.append(i)
        else:
            dropped.append(
                DroppedView(
                    i, names[i], f"{int((~ok).sum())} corners outside the {camera.name} model's field"
                )
            )
    return keep


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
        _max_angle({i: final.T_ref_board[k]}, {i: X[i][final.kept[k]]}, [i]) for k, i in enumerate(views)
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
