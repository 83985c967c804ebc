"""Rigid transforms and rotations: ``T_a_b`` maps points in frame b into frame a (docs/design.md,
"Conventions")."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "invert_transform",
    "is_rotation",
    "make_transform",
    "rot_x",
    "rot_y",
    "rot_z",
    "rotation_angle",
    "transform_points",
]

F64 = NDArray[np.float64]


def rot_x(angle: float) -> F64:
    """Rotation about x by ``angle`` radians, (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> F64:
    """Rotation about y by ``angle`` radians, (3, 3). Positive turns +z towards +x."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> F64:
    """Rotation about z by ``angle`` radians, (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def make_transform(R: ArrayLike, t: ArrayLike) -> F64:
    """4x4 homogeneous transform from rotation (3, 3) and translation (3,)."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, dtype=np.float64)
    T[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return T


def invert_transform(T: ArrayLike) -> F64:
    """Inverse of a rigid 4x4 transform without a general matrix inverse."""
    T = np.asarray(T, dtype=np.float64)
    R = T[:3, :3]
    return make_transform(R.T, -R.T @ T[:3, 3])


def transform_points(T: ArrayLike, points: ArrayLike) -> F64:
    """Apply a 4x4 transform to points (N, 3) -> (N, 3)."""
    M = np.asarray(T, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return p @ M[:3, :3].T + M[:3, 3]


def is_rotation(R: ArrayLike, tol: float = 1e-6) -> bool:
    """Whether R (3, 3) is a proper rotation: orthonormal within ``tol`` (``np.allclose``), det +1.
    Entries beyond 1 + tol are refused first: R Rᵀ of a malformed file's 1e200 would overflow."""
    R = np.asarray(R, dtype=np.float64)
    return bool(
        np.abs(R).max() <= 1.0 + tol and np.allclose(R @ R.T, np.eye(3), atol=tol) and np.linalg.det(R) > 0
    )


def rotation_angle(R: ArrayLike) -> float:
    """Angle in radians of a rotation matrix (3, 3); numerically safe near 0 and pi."""
    R = np.asarray(R, dtype=np.float64)
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    # atan2 form keeps precision for small angles where arccos loses it.
    s = np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2.0
    return float(np.arctan2(s, c))
