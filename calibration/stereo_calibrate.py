"""Extrinsic calibration of a camera pair, including strongly divergent ones (90° apart).

``calibrate_stereo``: each camera's intrinsics (given, or calibrated from all of its views with
:func:`calibrate_camera`), then the relative pose ``T_right_left`` from the views both cameras
see (per-view ``T_right_board · T_left_board⁻¹``, robustly averaged on SO(3)), then one joint
refinement of the relative pose, every board pose (in the left frame) and optionally both
cameras' intrinsics over all corners of all views. Nothing limits the angle off axis: corners
past 90° are kept (Kalibr drops them beyond 80°; OpenCV's fisheye stereo calibration cannot use
rays at or past 90°).

With each camera's images (``left_images``/``right_images``) the corners are refined for the
fisheye (:mod:`calibration.corner_refine`) with that camera's lens: within its own calibration,
or once with the given lens when intrinsics are fixed.

A chessboard seen from two very different directions may be detected with its corners in
opposite orders (a 180° turn of the board maps the grid onto itself). Each common view is
checked against both orders and the one consistent with the other views is used.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.board_views import MIN_CORNERS, DroppedView, prepare_views
from calibration.calibrate import CameraCalibration, FitOptions, calibrate_camera, check_loss, free_mask
from calibration.corner_refine import ImageSource, RefinementReport, refine_views
from calibration.errors import CalibrationError, CalibrationFailed
from calibration.geometry import invert_transform
from calibration.initial_guess import board_poses
from calibration.models.base import CameraModel
from calibration.pose_consensus import average_transforms, relative_pose
from calibration.rig import Rig
from calibration.solver import BundleResult, CameraBlock, Observation, refine_bundle

__all__ = ["StereoCalibration", "average_transforms", "calibrate_stereo"]

F64 = NDArray[np.float64]

_UNSEEN = "no corners detected"


@dataclass
class StereoCalibration:
    """Result of :func:`calibrate_stereo`. Per-view lists follow ``views`` (input indices);
    entries are None where that camera did not see the view."""

    rig: Rig
    T_right_left: F64  # (4, 4) p_right = T_right_left · p_left
    cameras: dict[str, CameraModel]
    rms: float  # px over the corners of both cameras
    camera_rms: dict[str, float]
    views: list[int]
    view_names: list[str]
    common_views: list[int]  # input indices of views seen by both cameras
    view_rms: dict[str, list[float | None]]
    image_points: dict[str, list[F64 | None]]
    residuals: dict[str, list[F64 | None]]
    rotation_std_deg: float  # 1-σ of the relative rotation (norm of the 3 axes)
    translation_std_m: float  # 1-σ of the relative translation (norm)
    param_std: dict[str, dict[str, float]]
    max_angle_deg: dict[str, float]
    mono: dict[str, CameraCalibration | None]  # per-camera calibration stage (None if given)
    dropped: list[tuple[str, DroppedView]] = field(default_factory=list)
    converged: bool = True
    message: str = ""
    refinement: dict[str, RefinementReport | None] = field(default_factory=dict)  # per camera

    @property
    def baseline_m(self) -> float:
        return float(np.linalg.norm(invert_transform(self.T_right_left)[:3, 3]))


def calibrate_stereo(
    model: str | tuple[str, str],
    object_points: Sequence[ArrayLike],
    left_points: Sequence[ArrayLike | None],
    right_points: Sequence[ArrayLike | None],
    image_size: tuple[int, int],
    right_image_size: tuple[int, int] | None = None,
    *,
    left_initial: CameraModel | None = None,
    right_initial: CameraModel | None = None,
    fix_intrinsics: bool = False,
    fix: Iterable[str] = (),
    fov_deg: float | None = None,
    names: tuple[str, str] = ("left", "right"),
    view_names: Sequence[str] | None = None,
    loss: str = "linear",
    min_views: int = 3,
    min_common_views: int = 3,
    left_images: Sequence[ImageSource | None] | None = None,
    right_images: Sequence[ImageSource | None] | None = None,
    refine_rounds: int = 3,
    refine_tol_px: float = 1e-3,
) -> StereoCalibration:
    """Calibrate a camera pair from board views; ``left_points[v]``/``right_points[v]`` are
    (N, 2) detections of ``object_points[v]`` (N, 3) or None where that camera missed view v.

    ``model`` names the camera model (one for both, or a pair). ``*_initial`` are optional
    starting guesses (any model; converted); with ``fix_intrinsics`` they are used as they are
    (or, when absent, each camera's own calibration) and held fixed while only poses are
    refined. ``fix``, ``fov_deg``, ``loss`` and ``min_views`` are passed to each camera's
    :func:`calibrate_camera`. Returns the relative pose, a Rig in the canonical rig frame
    (:meth:`Rig.from_relative_pose`) and per-camera errors. Raises CalibrationFailed with fewer
    than ``min_common_views`` views seen by both cameras.

    ``left_images``/``right_images`` (one per view: array, path or None) switch on corner
    refinement for that camera (``refine_rounds``, ``refine_tol_px``: see
    :func:`calibrate_camera`); ``result.refinement`` reports it per camera.
    """
    models = (model, model) if isinstance(model, str) else tuple(model)
    if len(models) != 2:
        raise CalibrationError(f"expected one model name or two, got {model!r}")
    check_loss(loss)
    w, h = (int(v) for v in image_size)
    rw, rh = (int(v) for v in right_image_size) if right_image_size is not None else (w, h)
    sizes = ((w, h), (rw, rh))
    initials = (left_initial, right_initial)
    cam_points = (left_points, right_points)
    images = (left_images, right_images)
    _check_view_counts(len(object_points), cam_points, images, names)
    vnames = list(view_names) if view_names is not None else [f"view {i}" for i in range(len(object_points))]
    options = FitOptions(tuple(fix), fov_deg, loss, min_views, refine_rounds, refine_tol_px)

    # ---- per-camera intrinsics and board poses ------------------------------------------------
    dropped: list[tuple[str, DroppedView]] = []
    stages: list[_CameraStage] = []
    for c, pts in enumerate(cam_points):
        if fix_intrinsics and (cam := initials[c]) is not None:
            stage = _fixed_camera(cam, object_points, pts, images[c], vnames, names[c], dropped)
        else:
            stage = _calibrated_camera(
                models[c], object_points, pts, sizes[c], initials[c], images[c], vnames, names[c], options,
                dropped,
            )  # fmt: skip
        stages.append(stage)

    # ---- relative pose from common views ------------------------------------------------------
    objs = stages[-1].objs
    poses = [stage.poses for stage in stages]
    points = [stage.points for stage in stages]
    T_rl, common = relative_pose(objs, poses, points, names[1], vnames, min_common_views, dropped)

    # ---- joint refinement ---------------------------------------------------------------------
    views = common if fix_intrinsics else sorted(set(poses[0]) | set(poses[1]))
    cams = [stage.camera for stage in stages]
    free = [_free(cam, options.fix, fix_intrinsics) for cam in cams]
    result, obs = _joint_refinement(cams, free, T_rl, objs, poses, points, views, loss)
    mono = {names[c]: stage.mono for c, stage in enumerate(stages)}
    out = _stereo_result(result, views, vnames, common, names, obs, mono, dropped)
    out.refinement = {names[c]: stage.refinement for c, stage in enumerate(stages)}
    return out


def _check_view_counts(
    n_views: int,
    cam_points: tuple[Sequence[ArrayLike | None], Sequence[ArrayLike | None]],
    images: tuple[Sequence[ImageSource | None] | None, Sequence[ImageSource | None] | None],
    names: tuple[str, str],
) -> None:
    """Every camera's image points and images (where given) are one per view."""
    left_points, right_points = cam_points
    if len(left_points) != n_views or len(right_points) != n_views:
        raise CalibrationError(
            f"{n_views} object point sets but {len(left_points)} left "
            f"and {len(right_points)} right image point sets"
        )
    for c, ims in enumerate(images):
        if ims is not None and len(ims) != n_views:
            raise CalibrationError(f"{len(ims)} {names[c]} images for {n_views} views")


@dataclass
class _CameraStage:
    """One camera before the joint refinement: its lens, board poses and corners by view (input
    index), the object points of every view, its own calibration (None: intrinsics given and
    fixed) and its corner refinement's report (None: no images)."""

    camera: CameraModel
    poses: dict[int, F64]
    points: dict[int, F64]
    objs: list[F64]
    mono: CameraCalibration | None
    refinement: RefinementReport | None


def _fixed_camera(
    cam: CameraModel,
    object_points: Sequence[ArrayLike],
    pts: Sequence[ArrayLike | None],
    cam_images: Sequence[ImageSource | None] | None,
    vnames: list[str],
    name: str,
    dropped: list[tuple[str, DroppedView]],
) -> _CameraStage:
    """Board poses under the given lens ``cam``, and with ``cam_images`` its corners refined."""
    objs, imgs, _, drop = prepare_views(object_points, pts, vnames)
    dropped += [(name, d) for d in drop if d.reason != _UNSEEN]
    use = [i for i, u in enumerate(imgs) if u is not None]
    cam_poses, rms = _fixed_camera_poses(cam, objs, imgs, use, vnames, name, dropped)
    pts_used: dict[int, F64] = {i: u for i in cam_poses if (u := imgs[i]) is not None}
    report = None
    if cam_images is not None:
        cam_poses, pts_used, report = _refine_fixed(
            cam, cam_images, objs, pts_used, rms, vnames, name, dropped
        )
    return _CameraStage(cam, cam_poses, pts_used, objs, None, report)


def _calibrated_camera(
    model: str,
    object_points: Sequence[ArrayLike],
    pts: Sequence[ArrayLike | None],
    size: tuple[int, int],
    initial: CameraModel | None,
    cam_images: Sequence[ImageSource | None] | None,
    vnames: list[str],
    name: str,
    options: FitOptions,
    dropped: list[tuple[str, DroppedView]],
) -> _CameraStage:
    """The camera's own calibration (:func:`calibrate_camera`) from all of its views."""
    try:
        res = calibrate_camera(
            model, object_points, pts, size, initial, fix=options.fix, fov_deg=options.fov_deg,
            loss=options.loss, min_views=options.min_views, view_names=vnames, images=cam_images,
            refine_rounds=options.refine_rounds, refine_tol_px=options.refine_tol_px,
        )  # fmt: skip
    except CalibrationFailed as err:
        raise CalibrationFailed(f"{name} camera: {err}") from err
    objs, imgs, _, _ = prepare_views(object_points, pts, vnames)
    # A view only the other camera saw is not a problem worth reporting.
    dropped += [(name, d) for d in res.dropped if imgs[d.index] is not None or d.reason != _UNSEEN]
    poses = dict(zip(res.views, res.T_cam_board, strict=True))
    return _CameraStage(res.camera, poses, {i: res.corners[i] for i in res.views}, objs, res, res.refinement)


def _joint_refinement(
    cams: list[CameraModel],
    free: list[NDArray[np.bool_]],
    T_rl: F64,
    objs: list[F64],
    poses: list[dict[int, F64]],
    points: list[dict[int, F64]],
    views: list[int],
    loss: str,
) -> tuple[BundleResult, list[Observation]]:
    """One refinement of the relative pose, every board pose in the left frame and the
    cameras' ``free`` parameters over all corners of ``views``; and its observations."""
    T_left_board = [poses[0][i] if i in poses[0] else invert_transform(T_rl) @ poses[1][i] for i in views]
    obs = [
        Observation(c, k, objs[i], points[c][i]) for k, i in enumerate(views) for c in (0, 1) if i in poses[c]
    ]
    blocks = [
        CameraBlock(cams[0], free[0]),
        CameraBlock(cams[1], free[1], T_cam_ref=T_rl, pose_free=True),
    ]
    return refine_bundle(blocks, T_left_board, obs, loss=loss), obs


def _free(camera: CameraModel, fix: Iterable[str], fix_intrinsics: bool) -> NDArray[np.bool_]:
    if fix_intrinsics:
        return np.zeros(len(camera.params), bool)
    return free_mask(camera, fix)


def _fixed_camera_poses(
    cam: CameraModel,
    objs: list[F64],
    imgs: list[F64 | None],
    use: list[int],
    vnames: list[str],
    name: str,
    dropped: list[tuple[str, DroppedView]],
) -> tuple[dict[int, F64], float]:
    """Board poses under fixed intrinsics (ray PnP, then per-view refinement) and their RMS."""
    U: dict[int, F64] = {i: u for i in use if (u := imgs[i]) is not None}
    finite = {i: np.isfinite(U[i]).all(axis=1) for i in U}
    found = board_poses(cam, [objs[i][finite[i]] for i in U], [U[i][finite[i]] for i in U])
    poses: dict[int, F64] = {}
    for i, T in zip(U, found, strict=True):
        if T is None:
            dropped.append((name, DroppedView(i, vnames[i], "no board pose fits the corners")))
        else:
            poses[i] = T
    if not poses:
        return poses, math.nan
    keys = sorted(poses)
    obs = [Observation(0, k, objs[i], U[i]) for k, i in enumerate(keys)]
    refined = refine_bundle(
        [CameraBlock(cam, np.zeros(len(cam.params), bool))], [poses[i] for i in keys], obs
    )
    return dict(zip(keys, refined.T_ref_board, strict=True)), refined.rms


def _refine_fixed(
    cam: CameraModel,
    images: Sequence[ImageSource | None],
    objs: list[F64],
    corners: dict[int, F64],
    rms_before: float,
    vnames: list[str],
    name: str,
    dropped: list[tuple[str, DroppedView]],
) -> tuple[dict[int, F64], dict[int, F64], RefinementReport]:
    """Corners refined with a fixed lens (one round: the lens does not change) and the board
    poses on them; views left with too few corners are dropped."""
    refined, rejected = refine_views(images, corners, cam, dict(enumerate(objs)), vnames)
    imgs: list[F64 | None] = [refined.get(i) for i in range(len(objs))]
    for i, u in refined.items():
        if int(np.isfinite(u).all(axis=1).sum()) < MIN_CORNERS:
            imgs[i] = None
            dropped.append((name, DroppedView(i, vnames[i], "too few corners left after corner refinement")))
    use = [i for i, u in enumerate(imgs) if u is not None]
    poses, rms = _fixed_camera_poses(cam, objs, imgs, use, vnames, name, dropped)
    shifts = np.concatenate([np.linalg.norm(refined[i] - corners[i], axis=1) for i in poses] or [np.zeros(0)])
    d = shifts[np.isfinite(shifts)]
    report = RefinementReport(
        rms_before=rms_before, rms_after=rms, rounds=1, changes_px=(float(d.max()) if d.size else 0.0,),
        converged=True, mean_shift_px=float(d.mean()) if d.size else 0.0, n_corners=int(d.size),
        rejected=tuple(r for r in rejected if r.view in poses),
    )  # fmt: skip
    return poses, {i: refined[i] for i in poses}, report


def _stereo_result(
    result: BundleResult,
    views: list[int],
    vnames: list[str],
    common: list[int],
    names: tuple[str, str],
    obs: list[Observation],
    mono: dict[str, CameraCalibration | None],
    dropped: list[tuple[str, DroppedView]],
) -> StereoCalibration:
    T_rl = result.T_cam_ref[1]
    cams = {names[0]: result.cameras[0], names[1]: result.cameras[1]}
    view_rms: dict[str, list[float | None]] = {n: [None] * len(views) for n in names}
    image_points: dict[str, list[F64 | None]] = {n: [None] * len(views) for n in names}
    residuals: dict[str, list[F64 | None]] = {n: [None] * len(views) for n in names}
    sq = {n: 0.0 for n in names}
    count = {n: 0 for n in names}
    max_angle = {n: 0.0 for n in names}
    for o, r, kept in zip(obs, result.residuals, result.kept, strict=True):
        n = names[o.camera]
        view_rms[n][o.view] = float(np.sqrt(np.mean(np.sum(r**2, axis=1))))
        image_points[n][o.view] = o.image_points[kept]
        residuals[n][o.view] = r
        sq[n] += float(np.sum(r**2))
        count[n] += len(r)
        T = result.T_cam_ref[o.camera] @ result.T_ref_board[o.view]
        p = o.object_points[kept] @ T[:3, :3].T + T[:3, 3]
        ang = np.degrees(np.arccos(np.clip(p[:, 2] / np.linalg.norm(p, axis=1), -1.0, 1.0)))
        max_angle[n] = max(max_angle[n], float(ang.max()))
    std = result.pose_std[1]
    param_std = {
        n: {
            k: float(s)
            for k, s in zip(result.cameras[c].param_layout, result.param_std[c], strict=True)
            if np.isfinite(s)
        }
        for c, n in enumerate(names)
    }
    return StereoCalibration(
        rig=Rig.from_relative_pose(result.cameras[0], result.cameras[1], T_rl, names),
        T_right_left=T_rl,
        cameras=cams,
        rms=result.rms,
        camera_rms={n: math.sqrt(sq[n] / max(count[n], 1)) for n in names},
        views=list(views),
        view_names=[vnames[i] for i in views],
        common_views=list(common),
        view_rms=view_rms,
        image_points=image_points,
        residuals=residuals,
        rotation_std_deg=float(np.degrees(np.linalg.norm(std[:3]))),
        translation_std_m=float(np.linalg.norm(std[3:])),
        param_std=param_std,
        max_angle_deg=max_angle,
        mono=mono,
        dropped=dropped,
        converged=result.success,
        message=result.message,
    )
