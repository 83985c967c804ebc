"""Initial values for calibration from no guess: board poses from rays, an equidistant focal
length by 1-D search, and conversion of one lens model into another.

Board poses come from a generalised PnP on unit rays: the rays are rotated so that their mean is
the z axis, which puts every ray of a planar board (all in one half-space) in front of a virtual
pinhole even when they are past 90° off the optical axis; ``cv2.solvePnP`` on those normalised
coordinates, then the rotation is undone.

Shapes: object points (N, 3), image points (N, 2), rays (N, 3), poses 4x4 ``T_cam_board``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares, minimize_scalar

from calibration.errors import CalibrationFailed, ModelError
from calibration.models.base import CameraModel, create
from calibration.solver import param_bounds, param_scales, with_params_keep_derived

__all__ = [
    "SEEDS",
    "board_pose_from_rays",
    "board_poses",
    "convert_model",
    "search_equidistant_focal",
    "seed_model",
    "view_rms",
]

F64 = NDArray[np.float64]

# Views used to score focal-length candidates.
_SEARCH_VIEWS = 12
# A board whose rays spread further than this from their mean direction is not planar-visible.
_MIN_COS_FROM_MEAN = 0.05


def _rotation_to_z(m: F64) -> F64:
    """Rotation (3, 3) taking unit vector ``m`` to +z (shortest arc)."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(m, z)
    s, c = np.linalg.norm(axis), float(m @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    R, _ = cv2.Rodrigues(axis / s * math.atan2(s, c))
    return np.asarray(R, dtype=np.float64)


def board_pose_from_rays(object_points: F64, rays: F64) -> F64 | None:
    """Pose ``T_cam_board`` (4x4) of a board from its points (N, 3) and their unit rays (N, 3)
    in the camera, or None when the geometry does not allow one (too few points, rays spread
    over more than a half-space, solver failure, points behind the camera)."""
    X = np.asarray(object_points, np.float64)
    r = np.asarray(rays, np.float64)
    if len(X) < 4:
        return None
    m = r.mean(axis=0)
    if np.linalg.norm(m) < 1e-9:
        return None
    m /= np.linalg.norm(m)
    if (r @ m).min() < _MIN_COS_FROM_MEAN:
        return None
    Rz = _rotation_to_z(m)
    q = r @ Rz.T
    xy = (q[:, :2] / q[:, 2:3]).reshape(-1, 1, 2)
    planar = np.allclose(X[:, 2], 0.0)
    # IPPE suits planar boards but can return NaN on exact (noise-free) data; SQPnP is general.
    methods = (cv2.SOLVEPNP_IPPE, cv2.SOLVEPNP_SQPNP) if planar else (cv2.SOLVEPNP_SQPNP,)
    rvec = tvec = None
    for flag in methods:
        try:
            ok, rv, tv = cv2.solvePnP(X.reshape(-1, 1, 3), xy, np.eye(3), None, flags=flag)
        except cv2.error:
            continue
        if ok and np.isfinite(rv).all() and np.isfinite(tv).all():
            rvec, tvec = rv, tv
            break
    if rvec is None or tvec is None:
        return None
    R, _ = cv2.Rodrigues(rvec)
    T = np.eye(4)
    T[:3, :3] = Rz.T @ R
    T[:3, 3] = Rz.T @ tvec.reshape(3)
    p = X @ T[:3, :3].T + T[:3, 3]
    if not np.isfinite(T).all() or ((p * r).sum(axis=1) <= 0).any():
        return None
    return T


def board_poses(
    model: CameraModel, object_points: Sequence[F64], image_points: Sequence[F64]
) -> list[F64 | None]:
    """Initial ``T_cam_board`` per view (None where no pose can be found) under ``model``."""
    out: list[F64 | None] = []
    for X, u in zip(object_points, image_points, strict=True):
        rays, ok = model.unproject(u, in_image=False)
        out.append(board_pose_from_rays(X[ok], rays[ok]) if ok.sum() >= 4 else None)
    return out


def view_rms(model: CameraModel, T_cam_board: F64, object_points: F64, image_points: F64) -> float:
    """RMS (px) of the reprojection of one view; inf where projection is invalid."""
    p = object_points @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    pix, ok = model.project(p, in_image=False)
    if not ok.all():
        return math.inf
    return float(np.sqrt(np.mean(np.sum((pix - image_points) ** 2, axis=1))))


def search_equidistant_focal(
    object_points: Sequence[F64], image_points: Sequence[F64], image_size: tuple[int, int]
) -> CameraModel:
    """Equidistant model (centre = image centre) whose focal length best explains the views.

    Score of a focal length: the median over views of the RMS after a ray-PnP pose. Coarse
    log-spaced search covering fields from 10° to 180° at the image corner, then a bounded
    1-D refinement around the best candidate. Raises CalibrationFailed if no focal length
    gives poses for most views.
    """
    w, h = image_size
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    half_diag = math.hypot(w, h) / 2.0
    # A dozen views spread over the set pin the focal length down as well as all of them.
    pick = np.unique(np.linspace(0, len(object_points) - 1, min(len(object_points), _SEARCH_VIEWS)).round())
    object_points = [object_points[int(i)] for i in pick]
    image_points = [image_points[int(i)] for i in pick]

    def score(log_f: float) -> float:
        f = math.exp(log_f)
        model = create("equidistant", w, h, fx=f, fy=f, cx=cx, cy=cy)
        errs = []
        for X, u, T in zip(
            object_points, image_points, board_poses(model, object_points, image_points), strict=True
        ):
            errs.append(math.inf if T is None else view_rms(model, T, X, u))
        return float(np.median(errs))

    grid = np.linspace(math.log(half_diag / math.pi), math.log(half_diag / math.radians(10.0)), 40)
    scores = np.array([score(g) for g in grid])
    if not np.isfinite(scores).any():
        raise CalibrationFailed("no focal length explains the detected corners (board poses not found)")
    i = int(np.argmin(scores))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    best = minimize_scalar(score, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    log_f = float(best.x) if best.fun <= scores[i] else float(grid[i])
    f = math.exp(log_f)
    return create("equidistant", w, h, fx=f, fy=f, cx=cx, cy=cy)


# ----- seeds: a model of each type close to an equidistant lens of focal f -----------------------

Seed = Callable[[int, int, float, float, float, float], dict[str, float]]

SEEDS: dict[str, Seed] = {
    "equidistant": lambda w, h, fx, fy, cx, cy: {"fx": fx, "fy": fy, "cx": cx, "cy": cy},
    "kannala_brandt": lambda w, h, fx, fy, cx, cy: {
        "fx": fx, "fy": fy, "cx": cx, "cy": cy, "k1": 0.0, "k2": 0.0, "k3": 0.0, "k4": 0.0,
    },
    # Near the axis r = f tan θ ≈ f θ.
    "pinhole": lambda w, h, fx, fy, cx, cy: {"fx": fx, "fy": fy, "cx": cx, "cy": cy},
    # ξ = 1 is the stereographic lens r = γ tan(θ/2) ≈ γ θ / 2.
    "mei": lambda w, h, fx, fy, cx, cy: {
        "xi": 1.0, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "fx": 2 * fx, "fy": 2 * fy, "cx": cx, "cy": cy,
    },
    # ξ = 0, α = 0.5 (and β = 1) is the same stereographic lens r = 2 f tan(θ/2) ≈ f θ.
    "double_sphere": lambda w, h, fx, fy, cx, cy: {
        "fx": fx, "fy": fy, "cx": cx, "cy": cy, "xi": 0.0, "alpha": 0.5,
    },
    "eucm": lambda w, h, fx, fy, cx, cy: {"fx": fx, "fy": fy, "cx": cx, "cy": cy, "alpha": 0.5, "beta": 1.0},
}  # fmt: skip


def seed_model(name: str, reference: CameraModel, theta_max: float) -> CameraModel:
    """A ``name`` model near ``reference`` (fx, fy, cx, cy read from it), before fitting."""
    fx, fy, cx, cy = (float(reference.param_dict[k]) for k in ("fx", "fy", "cx", "cy"))
    w, h = reference.width, reference.height
    if name == "scaramuzza":
        return _seed_scaramuzza(reference, theta_max)
    if name not in SEEDS:
        raise CalibrationFailed(f"no initialisation for camera model {name!r}; pass an initial guess")
    return create(name, w, h, **SEEDS[name](w, h, fx, fy, cx, cy))


def _seed_scaramuzza(reference: CameraModel, theta_max: float) -> CameraModel:
    """Scaramuzza's back-projection ``z(ρ) = a0 + a2 ρ² + a3 ρ³ + a4 ρ⁴`` fitted linearly to the
    reference lens: a ray at angle θ from radius ρ has z = ρ / tan θ. ρ is measured along the
    image's v axis, whose scale the stretch ``A = [[c, d], [e, 1]]`` keeps (c = fx / fy)."""
    fx, fy, cx, cy = (float(reference.param_dict[k]) for k in ("fx", "fy", "cx", "cy"))
    theta = np.linspace(0.02, min(theta_max, math.radians(175.0)), 60)
    rays = np.stack([np.zeros_like(theta), np.sin(theta), np.cos(theta)], axis=1)
    pix, _ = reference.project(rays, in_image=False)
    rho = np.abs(pix[:, 1] - cy)
    z = rho / np.tan(theta)
    A = np.stack([np.ones_like(rho), rho**2, rho**3, rho**4], axis=1)
    a, *_ = np.linalg.lstsq(A, z, rcond=None)
    return create(
        "scaramuzza",
        reference.width,
        reference.height,
        poly=tuple(float(v) for v in (a[0], 0.0, a[1], a[2], a[3])),
        cx=cx,
        cy=cy,
        c=fx / fy,
        d=0.0,
        e=0.0,
    )


def convert_model(
    reference: CameraModel, target: CameraModel, theta_max: float, free: NDArray[np.bool_] | None = None
) -> CameraModel:
    """Fit ``target``'s parameters (starting from its values) so that it projects like
    ``reference`` over the field ``θ ≤ theta_max`` (rays on a polar grid). Returns the fitted
    copy; raises CalibrationFailed if the fit cannot run."""
    theta = np.linspace(0.0, theta_max, 24)[1:]
    phi = np.linspace(0.0, 2 * math.pi, 24, endpoint=False)
    t2, p2 = np.meshgrid(theta, phi)
    tt, pp = t2.ravel(), p2.ravel()
    grid = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], axis=1)
    rays: F64 = np.vstack([[0.0, 0.0, 1.0], grid])
    ref_pix, ok = reference.project(rays, in_image=False)
    rays, ref_pix = rays[ok], ref_pix[ok]
    p0 = target.params
    mask = np.ones(len(p0), bool) if free is None else np.asarray(free, bool)
    # Solve in units of each parameter's typical magnitude (see param_scales).
    scale = param_scales(target)[mask]
    lo, hi = param_bounds(target)
    lo, hi = lo[mask] / scale, hi[mask] / scale

    def residual(q: F64) -> F64:
        p = p0.copy()
        p[mask] = q * scale
        try:
            model = with_params_keep_derived(target, p)
        except ModelError:
            return np.full(2 * len(rays), 1e4)
        pix, _ = model.project(rays, in_image=False)
        return (pix - ref_pix).ravel()

    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    q0 = np.clip(p0[mask] / scale, lo + 1e-9 * span, hi - 1e-9 * span)
    try:
        sol = least_squares(residual, q0, bounds=(lo, hi), x_scale="jac", method="trf", max_nfev=200)
    except (ValueError, np.linalg.LinAlgError) as err:
        raise CalibrationFailed(f"could not convert {reference.name} to {target.name}: {err}") from err
    p = p0.copy()
    p[mask] = sol.x * scale
    return target.with_params(p)
