"""Relative rotation (and, where the scene constrains it, baseline direction) of a camera pair
from ray correspondences: the self-calibration behind ``rig calibrate refine`` and the online
refinement (docs/rectification.md).

Unknowns, all small corrections of a prior ``T_right_left``:

* ``ω`` (3,): a rotation vector turning the right camera, expressed in a reference frame
  attached to the left camera (``R_left_ref``; the rectified pair's axes: x along the baseline,
  y down, z forward), so its components are pitch about the baseline, vergence about the
  vertical and roll about the look direction;
* ``(a, b)``: the baseline direction as two tangent coordinates on the unit sphere (``e1`` the
  reference y made orthogonal to the baseline, ``e2 = ĉ × e1``); the baseline's length (the
  scale) is never changed. The direction is estimated only where its marginal standard deviation
  from the information matrix is below ``max_direction_sigma_deg`` (a planar or distant scene
  leaves it unobservable, the rotation stays observable); otherwise it stays fixed and the result
  says why.

Residual of a match (rays ``f_l`` in the left, ``f_r`` in the right camera, unit): the symmetric
normalised epipolar error ``e = √2 f_r·(t̂×R f_l) / √(|t̂×R f_l|² + |t̂×f_r|²)``, the angle (rad)
by which the two rays miss a common epipolar plane; valid for rays past 90° off axis.

Estimation: RANSAC over minimal sets of three matches on the linearised rotation problem, a
Cauchy-robust fit (``scipy.optimize.least_squares``) from its consensus, then a plain least
squares on the inliers (within 3.5 robust standard deviations) that gives the estimate and its
covariance ``σ² (JᵀJ)⁻¹`` (σ² the inliers' residual variance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from calibration.errors import CalibrationFailed
from calibration.geometry import invert_transform, is_rotation, make_transform
from calibration.rig import Rig

__all__ = [
    "RelativePoseFit",
    "RelativePoseOptions",
    "epipolar_errors",
    "refine_relative_pose",
    "rig_with_relative_pose",
]

F64 = NDArray[np.float64]
Mask = NDArray[np.bool_]

# Rays closer than this (sine of the angle) to the baseline carry no epipolar information.
_MIN_SIN_TO_BASELINE = 0.1
# Inliers of the final fit: within this many robust standard deviations.
_INLIER_SIGMAS = 3.5
# Smallest robust scale (rad): keeps the Cauchy loss finite on noise-free synthetic rays.
_MIN_SCALE = 1e-7
_FD_STEP = 1e-6


@dataclass(frozen=True)
class RelativePoseOptions:
    """Knobs of :func:`refine_relative_pose` (angles in degrees, as users give them).

    ``inlier_threshold_deg``: RANSAC's consensus threshold (a few pixels of the lens's angular
    resolution); ``estimate_direction``: ``"auto"`` (where observable), ``"always"`` or
    ``"never"``; ``max_direction_sigma_deg``: the observability bound of ``"auto"``;
    ``min_inliers``: fewer consistent matches is :class:`CalibrationFailed`.
    """

    inlier_threshold_deg: float = 0.25
    ransac_iterations: int = 300
    estimate_direction: str = "auto"
    max_direction_sigma_deg: float = 0.05
    min_inliers: int = 30
    seed: int = 0

    def __post_init__(self) -> None:
        if self.estimate_direction not in ("auto", "always", "never"):
            raise ValueError(
                f"estimate_direction must be auto, always or never, got {self.estimate_direction!r}"
            )


@dataclass(frozen=True)
class RelativePoseFit:
    """The refined pose and what supports it.

    ``T_right_left`` (4, 4) refined (``p_right = T · p_left``; the baseline's length kept);
    ``rotation_deg`` (3,) the correction ω about the reference axes and ``rotation_sigma_deg``
    its 1σ; ``angle_deg`` ± ``angle_sigma_deg`` its magnitude. ``direction_estimated`` whether the
    baseline direction was refined, ``direction_deg`` (2,) its correction (tangent components
    along e1, e2) and ``direction_sigma_deg`` (2,) their 1σ (what it would have been, if fixed),
    ``direction_note`` why it was or was not. ``inliers`` (N,) the matches of the final fit;
    ``rms_before_deg`` / ``rms_after_deg`` their epipolar error under the prior and the result;
    ``sigma_deg`` the robust standard deviation of the residuals.
    """

    T_right_left: F64
    rotation_deg: F64
    rotation_sigma_deg: F64
    angle_deg: float
    angle_sigma_deg: float
    direction_estimated: bool
    direction_deg: F64
    direction_sigma_deg: F64
    direction_note: str
    inliers: Mask
    rms_before_deg: float
    rms_after_deg: float
    sigma_deg: float
    covariance: F64 = field(repr=False)

    @property
    def n_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))


def epipolar_errors(R_right_left: ArrayLike, t_right_left: ArrayLike, rays_left: F64, rays_right: F64) -> F64:
    """Symmetric normalised epipolar error (rad, signed) of each match (see module doc).
    ``rays_left`` / ``rays_right`` (N, 3) unit rays in their camera's frame; (N,)."""
    R = np.asarray(R_right_left, dtype=np.float64)
    t = np.asarray(t_right_left, dtype=np.float64)
    t_hat = t / np.linalg.norm(t)
    a = np.cross(t_hat, rays_left @ R.T)
    b = np.cross(t_hat, rays_right)
    den = np.sqrt(np.einsum("ij,ij->i", a, a) + np.einsum("ij,ij->i", b, b))
    return np.asarray(math.sqrt(2.0) * np.einsum("ij,ij->i", rays_right, a) / np.maximum(den, 1e-12))


class _Model:
    """Pose as a function of the unknowns (see module doc)."""

    def __init__(self, T_right_left: F64, R_left_ref: F64) -> None:
        self.R0 = T_right_left[:3, :3]
        c0 = -self.R0.T @ T_right_left[:3, 3]  # right centre in the left frame
        self.baseline = float(np.linalg.norm(c0))
        if not self.baseline > 0.0:
            raise CalibrationFailed("the two optical centres coincide: no baseline to refine against")
        self.c_hat = c0 / self.baseline
        self.R_lr = R_left_ref
        y = R_left_ref[:, 1] - (R_left_ref[:, 1] @ self.c_hat) * self.c_hat
        if np.linalg.norm(y) < 1e-6:  # reference y along the baseline: any orthogonal axis
            y = np.cross(self.c_hat, R_left_ref[:, 2])
        self.e1 = y / np.linalg.norm(y)
        self.e2 = np.cross(self.c_hat, self.e1)

    def pose(self, x: F64) -> tuple[F64, F64]:
        """(R_right_left, t_right_left) for unknowns ``x`` = ω (3,) [+ (a, b)]."""
        dR = Rotation.from_rotvec(x[:3]).as_matrix()
        R = self.R0 @ self.R_lr @ dR.T @ self.R_lr.T
        c = self.c_hat
        if x.size > 3:
            c = c + x[3] * self.e1 + x[4] * self.e2
            c = c / np.linalg.norm(c)
        return R, -R @ (self.baseline * c)

    def transform(self, x: F64) -> F64:
        R, t = self.pose(x)
        return make_transform(R, t)


def _robust_sigma(r: F64) -> float:
    return max(_MIN_SCALE, 1.4826 * float(np.median(np.abs(r))))


def _sigma_deg(cov: F64) -> F64:
    return np.asarray(np.degrees(np.sqrt(np.clip(np.diag(cov), 0.0, None))), dtype=np.float64)


class _Problem:
    """The matches (usable rays only) and the pose model: residuals, Jacobians and fits."""

    def __init__(self, model: _Model, rays_left: F64, rays_right: F64, opts: RelativePoseOptions) -> None:
        self.model = model
        self.fl, self.fr = rays_left, rays_right
        self.opts = opts
        self.threshold = math.radians(opts.inlier_threshold_deg)

    def residuals(self, x: F64) -> F64:
        R, t = self.model.pose(x)
        return epipolar_errors(R, t, self.fl, self.fr)

    def jacobian(self, x: F64, sel: Mask | None = None) -> F64:
        """Central differences of the residuals (of the ``sel`` matches) at ``x``: (N, len(x))."""
        cols = []
        for i in range(x.size):
            h = np.zeros_like(x)
            h[i] = _FD_STEP
            d = (self.residuals(x + h) - self.residuals(x - h)) / (2.0 * _FD_STEP)
            cols.append(d if sel is None else d[sel])
        return np.stack(cols, axis=1)

    def consensus(self) -> tuple[F64, Mask]:
        """RANSAC on the linearised rotation, relinearised until its step is small: a consensus
        found under a large error grows once that error is removed."""
        x = np.zeros(3)
        inl = np.zeros(self.fl.shape[0], dtype=bool)
        for _ in range(3):
            w, inl = self._ransac(self.residuals(x), self.jacobian(x))
            x = x + w
            if np.linalg.norm(w) < math.radians(0.01):
                break
        return x, inl

    def _ransac(self, r0: F64, J: F64) -> tuple[F64, Mask]:
        """Rotation step (3,) with the largest consensus of ``r0 + J ω`` within the threshold."""
        rng = np.random.default_rng(self.opts.seed)
        best_w: F64 = np.zeros(3)
        best_in: Mask = np.abs(r0) < self.threshold
        for _ in range(self.opts.ransac_iterations):
            idx = rng.choice(r0.size, 3, replace=False)
            if abs(np.linalg.det(J[idx])) < 1e-12:
                continue
            w = np.asarray(np.linalg.solve(J[idx], -r0[idx]), dtype=np.float64)
            inl = np.abs(r0 + J @ w) < self.threshold
            if inl.sum() > best_in.sum():
                best_w, best_in = w, inl
        if best_in.sum() >= 3:
            best_w = np.asarray(np.linalg.lstsq(J[best_in], -r0[best_in], rcond=None)[0], dtype=np.float64)
            best_in = np.abs(r0 + J @ best_w) < self.threshold
        return best_w, best_in

    def robust_fit(self, x0: F64, scale: float) -> tuple[F64, Mask]:
        """Cauchy-robust fit from ``x0``; the inliers (within 3.5 robust σ and the threshold)."""
        x = np.asarray(least_squares(self.residuals, x0, loss="cauchy", f_scale=scale, x_scale=1e-3).x)
        r = self.residuals(x)
        sel = np.abs(r) < min(self.threshold, _INLIER_SIGMAS * _robust_sigma(r[np.abs(r) < self.threshold]))
        if sel.sum() < self.opts.min_inliers:
            raise CalibrationFailed(
                f"not enough consistent matches: {int(sel.sum())} inliers, need {self.opts.min_inliers}"
            )
        return x, sel

    def information(self, x: F64, sel: Mask) -> tuple[F64, float]:
        """``JᵀJ`` of the ``sel`` matches at ``x`` and their residual variance."""
        J = self.jacobian(x, sel)
        r = self.residuals(x)[sel]
        return J.T @ J, float(r @ r) / max(1, r.size - x.size)

    def plain_fit(self, x0: F64, sel: Mask) -> tuple[F64, F64]:
        """Plain least squares on the ``sel`` matches from ``x0``: (x, covariance σ² (JᵀJ)⁻¹)."""

        def sub(x: F64) -> F64:
            return self.residuals(x)[sel]

        x = np.asarray(least_squares(sub, x0, method="lm", x_scale=1e-3).x)
        info, s2 = self.information(x, sel)
        if np.linalg.cond(info) > 1e12:
            raise CalibrationFailed("the matches do not constrain the rotation (all in one small region?)")
        return x, np.asarray(s2 * np.linalg.inv(info), dtype=np.float64)

    def direction_sigma_deg(self, x_rot: F64, sel: Mask) -> F64:
        """1σ (deg) the baseline direction's two components would have if estimated too."""
        info, s2 = self.information(np.concatenate([x_rot, np.zeros(2)]), sel)
        if np.linalg.cond(info) > 1e14:
            return np.full(2, np.inf)
        return _sigma_deg(np.asarray(s2 * np.linalg.pinv(info), dtype=np.float64))[3:]


def _check_inputs(
    rays_left: ArrayLike, rays_right: ArrayLike, T: ArrayLike, R_ref: ArrayLike | None
) -> tuple[F64, F64, F64, F64]:
    fl = np.asarray(rays_left, dtype=np.float64).reshape(-1, 3)
    fr = np.asarray(rays_right, dtype=np.float64).reshape(-1, 3)
    if fl.shape != fr.shape:
        raise ValueError(f"rays_left {fl.shape} and rays_right {fr.shape} must have the same shape")
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all() or not is_rotation(T[:3, :3]):
        raise ValueError("T_right_left must be a rigid 4x4 transform")
    R_lr = np.eye(3) if R_ref is None else np.asarray(R_ref, dtype=np.float64)
    if R_lr.shape != (3, 3) or not is_rotation(R_lr):
        raise ValueError("R_left_ref must be a 3x3 rotation")
    return fl, fr, T, R_lr


def _usable(model: _Model, fl: F64, fr: F64) -> Mask:
    """Finite, non-zero rays not too close to the baseline (the epipoles say nothing about the
    epipolar planes)."""
    with np.errstate(invalid="ignore"):
        n_l, n_r = np.linalg.norm(fl, axis=1), np.linalg.norm(fr, axis=1)
        ok = np.isfinite(n_l) & np.isfinite(n_r) & (n_l > 0) & (n_r > 0)
        ul = np.where(ok[:, None], fl / np.where(ok, n_l, 1.0)[:, None], 0.0)
        ur = np.where(ok[:, None], fr / np.where(ok, n_r, 1.0)[:, None], 0.0)
    s_l = np.linalg.norm(np.cross(model.c_hat, ul), axis=1)
    s_r = np.linalg.norm(np.cross(model.R0 @ model.c_hat, ur), axis=1)
    return np.asarray(ok & (s_l > _MIN_SIN_TO_BASELINE) & (s_r > _MIN_SIN_TO_BASELINE))


def refine_relative_pose(
    rays_left: ArrayLike,
    rays_right: ArrayLike,
    T_right_left: ArrayLike,
    R_left_ref: ArrayLike | None = None,
    options: RelativePoseOptions | None = None,
) -> RelativePoseFit:
    """Refine ``T_right_left`` (4, 4) from matched rays (N, 3) of the left and right cameras
    (see the module doc). ``R_left_ref`` (3, 3): columns are the reference axes in the left
    camera's frame (default: the left camera's own). Raises :class:`CalibrationFailed` when too
    few matches agree or they do not constrain the rotation; ValueError for malformed input.

    The inlier mask refers to the rays as given (unusable rows are never inliers).
    """
    opts = options or RelativePoseOptions()
    fl, fr, T0, R_lr = _check_inputs(rays_left, rays_right, T_right_left, R_left_ref)
    model = _Model(T0, R_lr)
    usable = _usable(model, fl, fr)
    if usable.sum() < opts.min_inliers:
        raise CalibrationFailed(f"not enough matches: {int(usable.sum())}, need at least {opts.min_inliers}")
    fu, ru = fl[usable], fr[usable]
    prob = _Problem(
        model,
        fu / np.linalg.norm(fu, axis=1, keepdims=True),
        ru / np.linalg.norm(ru, axis=1, keepdims=True),
        opts,
    )
    x3, inl = prob.consensus()
    if inl.sum() < opts.min_inliers:
        raise CalibrationFailed(
            f"not enough consistent matches: {int(inl.sum())} of {inl.size} agree on one rotation, "
            f"need at least {opts.min_inliers}"
        )
    scale = _robust_sigma(prob.residuals(x3)[inl])
    x3, sel = prob.robust_fit(x3, scale)
    x, cov = prob.plain_fit(x3, sel)
    dir_sigma = prob.direction_sigma_deg(x, sel)
    observable = bool(np.all(dir_sigma <= opts.max_direction_sigma_deg))
    estimate = opts.estimate_direction == "always" or (opts.estimate_direction == "auto" and observable)
    if estimate:
        x5, sel = prob.robust_fit(np.concatenate([x, np.zeros(2)]), scale)
        x, cov = prob.plain_fit(x5, sel)
        dir_sigma = _sigma_deg(cov)[3:]
    inliers = np.zeros(fl.shape[0], dtype=bool)
    inliers[np.flatnonzero(usable)[sel]] = True
    return _fit_result(
        prob, x, cov, inliers, sel, dir_sigma, _direction_note(opts, estimate, observable, dir_sigma)
    )


def _direction_note(opts: RelativePoseOptions, estimate: bool, observable: bool, sigma: F64) -> str:
    bound = f"{opts.max_direction_sigma_deg:g}°"
    if estimate and observable:
        return f"estimated (1σ {sigma.max():.3f}° ≤ {bound})"
    if estimate:
        return f"estimated on request, weakly constrained (1σ {sigma.max():.3f}° > {bound})"
    if opts.estimate_direction == "never":
        return "kept (not estimated, on request)"
    return (
        f"kept: the scene does not constrain it (1σ would be {sigma.max():.3f}° > {bound}; "
        "a distant or planar scene)"
    )


def _fit_result(
    prob: _Problem, x: F64, cov: F64, inliers: Mask, sel: Mask, dir_sigma: F64, note: str
) -> RelativePoseFit:
    rot_cov = cov[:3, :3]
    w = x[:3]
    angle = float(np.linalg.norm(w))
    axis = w / angle if angle > 0 else np.array([1.0, 0.0, 0.0])
    r_final = prob.residuals(x)[sel]
    r_prior = prob.residuals(np.zeros(x.size))[sel]
    return RelativePoseFit(
        T_right_left=prob.model.transform(x),
        rotation_deg=np.degrees(w),
        rotation_sigma_deg=_sigma_deg(rot_cov),
        angle_deg=math.degrees(angle),
        angle_sigma_deg=math.degrees(math.sqrt(max(0.0, float(axis @ rot_cov @ axis)))),
        direction_estimated=x.size > 3,
        direction_deg=np.degrees(x[3:5]) if x.size > 3 else np.zeros(2),
        direction_sigma_deg=dir_sigma,
        direction_note=note,
        inliers=inliers,
        rms_before_deg=math.degrees(math.sqrt(float(np.mean(r_prior**2)))),
        rms_after_deg=math.degrees(math.sqrt(float(np.mean(r_final**2)))),
        sigma_deg=math.degrees(_robust_sigma(r_final)),
        covariance=cov,
    )


def rig_with_relative_pose(rig: Rig, left: str, right: str, T_right_left: ArrayLike) -> Rig:
    """``rig`` with camera ``right`` moved so that its pose relative to ``left`` is
    ``T_right_left`` (4, 4); every other camera and ``left`` keep their poses in the rig frame."""
    T = np.asarray(T_right_left, dtype=np.float64)
    poses = {n: p.copy() for n, p in rig.T_rig_cam.items()}
    poses[right] = rig.T_rig_cam[left] @ invert_transform(T)
    return Rig(dict(rig.cameras), poses, rig.pairs)
