"""The paper's accuracy measures (§IV-A) and the helpers around them, as pure functions.

Depth quality of one depth map of a plane: the valid pixels become 3D points in the left VPC
frame; points further from the true plane than ``vicinity_frac`` × its distance are discarded
(gross mismatches, the background); ``samples`` random points (seeded) of the rest give the
error ``estimated z − true z``: its RMS and standard deviation (ddof 0, so RMS² = mean² + std²).
Then a 2nd-order polynomial of RMS against distance, and the theoretical stereo error
``σZ = Z²·σd / (fx·B)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.models import PinholeModel
from rig.depth import depth_points
from rig.errors import EvaluationError

__all__ = [
    "DisparityStats",
    "Plane",
    "PlaneStats",
    "disparity_stats",
    "finite_mean",
    "fit_quadratic",
    "image_difference",
    "loglog_slope",
    "plane_depth_stats",
    "plane_in_frame",
    "sample_indices",
    "theory_sigma_z",
    "vicinity_mask",
]

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Plane:
    """Points p with ``normal · p = offset`` (``normal`` (3,) unit)."""

    normal: F64
    offset: float


def plane_in_frame(T_world_frame: ArrayLike, normal_world: ArrayLike, offset_world: float) -> Plane:
    """A world plane ``n·p = d`` expressed in a frame posed at ``T_world_frame`` (4, 4)."""
    T = np.asarray(T_world_frame, dtype=np.float64)
    n = np.asarray(normal_world, dtype=np.float64)
    n = n / np.linalg.norm(n)
    R, t = T[:3, :3], T[:3, 3]
    # n·(R p + t) = d  <=>  (Rᵀ n)·p = d − n·t
    return Plane(R.T @ n, float(offset_world - n @ t))


def vicinity_mask(points: ArrayLike, plane: Plane, tolerance_m: float) -> NDArray[np.bool_]:
    """(N,) True where points (N, 3) lie within ``tolerance_m`` of ``plane``."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return np.asarray(np.abs(p @ plane.normal - plane.offset) <= tolerance_m)


def sample_indices(n: int, count: int, rng: np.random.Generator) -> NDArray[np.intp]:
    """``min(count, n)`` distinct indices of range(n), in random order (all of them when n ≤
    count, so a small set is used whole rather than resampled)."""
    if n < 0 or count < 0:
        raise EvaluationError(f"cannot sample {count} of {n} points")
    return np.asarray(rng.choice(n, size=min(count, n), replace=False), dtype=np.intp)


@dataclass(frozen=True)
class PlaneStats:
    """Depth error of one depth map of a plane (NaN fields when no point is near the plane).

    ``rms_m``/``std_m``/``mean_m`` of estimated − true z over the sampled points;
    ``valid_frac``: pixels with a depth near the plane / pixels that see the plane;
    ``n_points``: points near the plane (before sampling); ``disparity_rms_px``: RMS of the
    sampled points' disparity error ``fx·B/z − fx·B/z_true``.
    """

    rms_m: float
    std_m: float
    mean_m: float
    valid_frac: float
    n_points: int
    disparity_rms_px: float


def plane_depth_stats(
    depth: F32,
    depth_true: F32,
    camera: PinholeModel,
    plane: Plane,
    rng: np.random.Generator,
    *,
    baseline_m: float,
    vicinity_frac: float = 0.1,
    samples: int = 1000,
) -> PlaneStats:
    """The paper's measure for ``depth`` (H, W) float32 m (NaN invalid) of ``plane`` (in the
    VPC frame of ``camera``) against the exact ``depth_true`` (H, W) (NaN where no surface)."""
    if depth.shape != depth_true.shape:
        raise EvaluationError(f"depth map {depth.shape} and ground truth {depth_true.shape} differ in size")
    sees_plane = int(np.count_nonzero(np.isfinite(depth_true)))
    pts, idx = depth_points(depth, camera)
    near = vicinity_mask(pts, plane, vicinity_frac * abs(plane.offset))
    z_true = depth_true.reshape(-1)[idx[near]].astype(np.float64)
    z_est = pts[near, 2].astype(np.float64)
    have_truth = np.isfinite(z_true)
    z_true, z_est = z_true[have_truth], z_est[have_truth]
    n = int(z_true.shape[0])
    valid_frac = n / sees_plane if sees_plane else 0.0
    if n == 0:
        return PlaneStats(math.nan, math.nan, math.nan, valid_frac, 0, math.nan)
    pick = sample_indices(n, samples, rng)
    err = z_est[pick] - z_true[pick]
    fb = camera.fx * baseline_m
    d_err = fb / z_est[pick] - fb / z_true[pick]
    return PlaneStats(
        rms_m=float(np.sqrt(np.mean(err**2))),
        std_m=float(np.std(err)),
        mean_m=float(np.mean(err)),
        valid_frac=valid_frac,
        n_points=n,
        disparity_rms_px=float(np.sqrt(np.mean(d_err**2))),
    )


@dataclass(frozen=True)
class DisparityStats:
    """Disparity error against the truth over the pixels that see a surface.

    ``rms_px`` over every valid pixel (gross errors included); ``rms_inlier_px`` over those within
    1 px; ``bad1_frac`` fraction of valid pixels off by more than 1 px; ``valid_frac`` valid /
    pixels with truth.
    """

    rms_px: float
    rms_inlier_px: float
    bad1_frac: float
    valid_frac: float


def disparity_stats(disparity: F32, disparity_true: F32) -> DisparityStats:
    """Stats of ``disparity`` (H, W) px (NaN invalid) against ``disparity_true`` (H, W)."""
    truth = np.isfinite(disparity_true)
    ok = truth & np.isfinite(disparity)
    n_truth = int(np.count_nonzero(truth))
    if not ok.any():
        return DisparityStats(math.nan, math.nan, math.nan, 0.0)
    e = (disparity[ok] - disparity_true[ok]).astype(np.float64)
    inl = np.abs(e) <= 1.0
    return DisparityStats(
        rms_px=float(np.sqrt(np.mean(e**2))),
        rms_inlier_px=float(np.sqrt(np.mean(e[inl] ** 2))) if inl.any() else math.nan,
        bad1_frac=float(np.mean(~inl)),
        valid_frac=float(np.count_nonzero(ok)) / n_truth,
    )


def finite_mean(values: ArrayLike) -> float:
    """Mean of the finite values; NaN when there are none."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else math.nan


def fit_quadratic(k: ArrayLike, values: ArrayLike) -> tuple[float, float, float] | None:
    """Least-squares ``a2·k² + a1·k + a0`` through the finite (k, value) pairs: (a2, a1, a0),
    or None with fewer than three of them."""
    x = np.asarray(k, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    if np.unique(x[ok]).shape[0] < 3:
        return None
    a2, a1, a0 = np.polyfit(x[ok], y[ok], 2)
    return float(a2), float(a1), float(a0)


def loglog_slope(k: ArrayLike, values: ArrayLike) -> float:
    """Exponent p of the best power law ``value ∝ k^p`` (least squares in log-log); NaN with
    fewer than two positive finite points."""
    x = np.asarray(k, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    if np.unique(x[ok]).shape[0] < 2:
        return math.nan
    return float(np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)[0])


def theory_sigma_z(z_m: ArrayLike, sigma_d_px: float, fx_px: float, baseline_m: float) -> F64:
    """Stereo depth error ``σZ = Z²·σd / (fx·B)`` (first-order propagation of a disparity error
    σd through ``Z = fx·B/d``), metres, same shape as ``z_m``."""
    z = np.asarray(z_m, dtype=np.float64)
    out: F64 = z * z * float(sigma_d_px) / (float(fx_px) * float(baseline_m))
    return out


def image_difference(
    image: NDArray[np.uint8], reference: NDArray[np.uint8], valid: NDArray[np.bool_]
) -> tuple[float, float, NDArray[np.uint8]]:
    """Mean absolute grey-level difference over ``valid`` pixels, the whole image and its
    central 50 % × 50 %, and the difference image |image − reference| (H, W) uint8 (0 where
    not valid). NaN means where no pixel is valid."""
    if image.shape != reference.shape or image.shape[:2] != valid.shape:
        raise EvaluationError(
            f"image {image.shape}, reference {reference.shape} and mask {valid.shape} differ in size"
        )
    diff = np.abs(image.astype(np.int16) - reference.astype(np.int16)).astype(np.uint8)
    if diff.ndim == 3:
        diff = diff.max(axis=2)
    diff[~valid] = 0
    h, w = valid.shape
    centre = (slice(h // 4, h - h // 4), slice(w // 4, w - w // 4))

    def mad(sel: tuple[slice, slice]) -> float:
        v = valid[sel]
        return float(diff[sel][v].mean()) if v.any() else math.nan

    return mad((slice(None), slice(None))), mad(centre), diff
