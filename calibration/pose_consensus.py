"""Relative pose of a camera pair from per-view estimates: a robust consensus over the views
(each possibly seen with its board's corners numbered the other way round) and the mean of
rigid transforms.

Shapes: transforms 4x4 (``T_right_left``), object points (N, 3).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from calibration.board_views import DroppedView
from calibration.errors import CalibrationFailed
from calibration.geometry import invert_transform

__all__ = ["average_transforms", "consensus_pose", "half_turn", "relative_pose"]

F64 = NDArray[np.float64]

# Two per-view relative poses agree when within these (robust consensus for the initial pose).
_AGREE_DEG = 3.0
_AGREE_FRACTION = 0.1  # of the median baseline


def average_transforms(transforms: Sequence[F64]) -> F64:
    """Mean of rigid transforms (4x4): chordal L2 mean of the rotations (SVD projection of the
    summed matrices onto SO(3)) and mean translation."""
    Rs = np.stack([T[:3, :3] for T in transforms])
    U, _, Vt = np.linalg.svd(Rs.sum(axis=0))
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = np.mean([T[:3, 3] for T in transforms], axis=0)
    return out


def _angle_deg(Ra: F64, Rb: F64) -> float:
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def half_turn(object_points: F64) -> F64 | None:
    """Transform F (4x4) of the board onto itself by a half turn about its centre when the
    reversed point order is that half turn (``X[::-1] == F · X``), else None."""
    c = 0.5 * (object_points.min(axis=0) + object_points.max(axis=0))
    F = np.eye(4)
    F[:3, :3] = np.diag([-1.0, -1.0, 1.0])
    F[:3, 3] = [2 * c[0], 2 * c[1], 0.0]
    turned = object_points @ F[:3, :3].T + F[:3, 3]
    scale = max(float(np.ptp(object_points, axis=0).max()), 1e-12)
    if not np.allclose(object_points[:, 2], 0.0) or not np.allclose(
        turned, object_points[::-1], atol=1e-9 * scale
    ):
        return None
    return F


def consensus_pose(candidates: list[list[F64]]) -> tuple[F64, list[int]]:
    """Pick per view one of its candidate relative poses so that most views agree; returns the
    averaged pose and the chosen candidate index per view (-1 = outlier)."""
    flat = [(v, k, T) for v, cands in enumerate(candidates) for k, T in enumerate(cands)]
    baseline = float(np.median([np.linalg.norm(T[:3, 3]) for _, _, T in flat]))
    t_tol = max(_AGREE_FRACTION * baseline, 1e-9)
    best: tuple[int, list[int]] = (-1, [])
    for _, _, ref in flat:
        choice = []
        for cands in candidates:
            ok = [
                k
                for k, T in enumerate(cands)
                if _angle_deg(T[:3, :3], ref[:3, :3]) < _AGREE_DEG
                and np.linalg.norm(T[:3, 3] - ref[:3, 3]) < t_tol
            ]
            choice.append(ok[0] if ok else -1)
        support = sum(c >= 0 for c in choice)
        if support > best[0]:
            best = (support, choice)
    choice = best[1]
    chosen = [candidates[v][k] for v, k in enumerate(choice) if k >= 0]
    return average_transforms(chosen), choice


def relative_pose(
    objs: list[F64],
    poses: list[dict[int, F64]],
    points: list[dict[int, F64]],
    right_name: str,
    vnames: list[str],
    min_common_views: int,
    dropped: list[tuple[str, DroppedView]],
) -> tuple[F64, list[int]]:
    """``T_right_left`` from the views both cameras see: each view's relative pose, with the
    right camera's corners in either order (:func:`half_turn`), and their consensus. A view
    whose right corners are numbered the other way round is turned (``points`` and ``poses``
    in place); one disagreeing with the others loses its right pose. Returns the pose and the
    common views left."""
    common = sorted(set(poses[0]) & set(poses[1]))
    if len(common) < min_common_views:
        raise CalibrationFailed(
            f"only {len(common)} view(s) with the board seen by both cameras, "
            f"need at least {min_common_views}"
        )
    candidates: list[list[F64]] = []
    flips: list[F64 | None] = []
    for i in common:
        F = half_turn(objs[i])
        flips.append(F)
        T = poses[1][i] @ invert_transform(poses[0][i])
        cands = [T]
        if F is not None:
            cands.append(poses[1][i] @ F @ invert_transform(poses[0][i]))
        candidates.append(cands)
    T_rl, choice = consensus_pose(candidates)
    for i, k, F in zip(common, choice, flips, strict=True):
        if k == 1 and F is not None:
            # The right camera numbered this board's corners the other way round.
            points[1][i] = points[1][i][::-1].copy()
            poses[1][i] = poses[1][i] @ F
        elif k < 0:
            dropped.append(
                (right_name, DroppedView(i, vnames[i], "relative pose disagrees with the other views"))
            )
            del poses[1][i]
    common = sorted(set(poses[0]) & set(poses[1]))
    if len(common) < min_common_views:
        raise CalibrationFailed(
            f"only {len(common)} view(s) give a consistent relative pose, need at least {min_common_views}"
        )
    return T_rl, common
