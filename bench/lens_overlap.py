"""The same scene points seen by two neighbouring cameras of the real ring (``bench.lens_fit``):
their brightness in each, and where each sees them (relative field). The ratio of the two
brightnesses depends on the lenses' rim darkening at the two field angles and on the cameras'
exposures, not on the scene (a matte surface looks equally bright from both), so many such points
fit the relative illumination and the exposure differences together.

Points: SIFT features matched between the adjacent cameras (1|2, 2|3, 3|4, 4|1) of each frame
(Lowe's ratio 0.8), kept where the two rays meet the ring's calibrated poses' epipolar plane
within :data:`EPIPOLAR_DEG` and cross in front of both cameras. Brightness: the mean over a
square of half the feature's size around it in each image (the same patch of the scene at the
two scales).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from bench.lens_data import LensCamera

__all__ = ["EPIPOLAR_DEG", "OverlapSamples", "ring_overlap"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

EPIPOLAR_DEG = 0.25
_ADJACENT = ((0, 1), (1, 2), (2, 3), (3, 0))


@dataclass(frozen=True)
class OverlapSamples:
    """Per matched point: the two cameras' indices, relative fields and mean grey levels."""

    cam_a: I64
    cam_b: I64
    x_a: F64
    x_b: F64
    grey_a: F64
    grey_b: F64


def _poses(path: Path) -> list[tuple[F64, F64]]:
    """Per camera (R, t) with P_rig = R P_cam + t, t in metres (the data set's poses.txt)."""
    rows = np.loadtxt(path)
    return [(cv2.Rodrigues(r[:3])[0], r[3:] / 1000.0) for r in rows]


def _box_mean(integral: F64, x: F64, y: F64, half: F64) -> F64:
    h, w = integral.shape[0] - 1, integral.shape[1] - 1
    x0 = np.clip(np.rint(x - half), 0, w - 1).astype(np.int64)
    x1 = np.clip(np.rint(x + half) + 1, 1, w).astype(np.int64)
    y0 = np.clip(np.rint(y - half), 0, h - 1).astype(np.int64)
    y1 = np.clip(np.rint(y + half) + 1, 1, h).astype(np.int64)
    total = integral[y1, x1] - integral[y0, x1] - integral[y1, x0] + integral[y0, x0]
    out: F64 = total / ((x1 - x0) * (y1 - y0))
    return out


def _consistent(
    ray_a: F64, ray_b: F64, pose_a: tuple[F64, F64], pose_b: tuple[F64, F64]
) -> NDArray[np.bool_]:
    """Rays (rig frame) that meet within EPIPOLAR_DEG of the epipolar plane, in front of both."""
    (Ra, ta), (Rb, tb) = pose_a, pose_b
    da, db, base = ray_a @ Ra.T, ray_b @ Rb.T, tb - ta
    normal = np.cross(da, base[None, :])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    off = np.degrees(np.arcsin(np.clip(np.abs(np.einsum("ij,ij->i", normal, db)), 0.0, 1.0)))
    # Closest points of the two lines: both ray parameters positive.
    b = np.einsum("ij,ij->i", da, db)
    wa, wb = da @ base, db @ base
    denom = 1.0 - b * b
    sa = (wa - b * wb) / np.where(denom > 1e-12, denom, np.nan)
    sb = (b * wa - wb) / np.where(denom > 1e-12, denom, np.nan)
    return np.asarray((off < EPIPOLAR_DEG) & (sa > 0.05) & (sb > 0.05))


def ring_overlap(cams: list[LensCamera], poses_path: Path) -> OverlapSamples:
    """Matched points of every frame and adjacent pair of the ring's four cameras."""
    poses = _poses(poses_path)
    sift = cv2.SIFT_create()  # type: ignore[attr-defined]
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    parts: list[tuple[int, int, F64, F64, F64, F64]] = []
    for frame in range(len(cams[0].images)):
        feats = []
        for cam in cams:
            keep = cv2.erode(cam.valid.astype(np.uint8), np.ones((9, 9), np.uint8))
            kps, desc = sift.detectAndCompute(cam.images[frame], keep)
            feats.append(
                (kps, desc, np.asarray(cv2.integral(cam.images[frame].astype(np.float64)), np.float64))
            )
        for a, b in _ADJACENT:
            (ka, da, ia), (kb, db, ib) = feats[a], feats[b]
            pairs = [
                m[0]
                for m in matcher.knnMatch(da, db, k=2)
                if len(m) == 2 and m[0].distance < 0.8 * m[1].distance
            ]
            pa = np.array([ka[m.queryIdx].pt for m in pairs])
            pb = np.array([kb[m.trainIdx].pt for m in pairs])
            sa = np.array([ka[m.queryIdx].size for m in pairs])
            sb = np.array([kb[m.trainIdx].size for m in pairs])
            model_a, model_b = cams[a].model, cams[b].model
            assert model_a is not None and model_b is not None
            ra, oka = model_a.unproject(pa)
            rb, okb = model_b.unproject(pb)
            ok = oka & okb & _consistent(ra, rb, poses[a], poses[b])
            xa = cams[a].x[np.rint(pa[ok, 1]).astype(int), np.rint(pa[ok, 0]).astype(int)]
            xb = cams[b].x[np.rint(pb[ok, 1]).astype(int), np.rint(pb[ok, 0]).astype(int)]
            ga = _box_mean(ia, pa[ok, 0], pa[ok, 1], np.maximum(1.0, 0.25 * sa[ok]))
            gb = _box_mean(ib, pb[ok, 0], pb[ok, 1], np.maximum(1.0, 0.25 * sb[ok]))
            parts.append((a, b, xa, xb, ga, gb))
    return OverlapSamples(
        np.concatenate([np.full(p[2].size, p[0]) for p in parts]),
        np.concatenate([np.full(p[2].size, p[1]) for p in parts]),
        *(np.concatenate([p[k] for p in parts]) for k in range(2, 6)),
    )
