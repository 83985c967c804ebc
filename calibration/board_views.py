"""One camera's board views during its calibration: checked, and dropped with the reason
when a fit cannot use them (too few corners, no pose, far off the others, outside the model's
field).

Shapes: object points (N, 3) per view (board frame), image points (N, 2) per view (NaN rows =
corner not detected), poses 4x4 ``T_cam_board``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.errors import CalibrationError, CalibrationFailed
from calibration.models.base import CameraModel
from calibration.solver import BundleResult

__all__ = [
    "MIN_CORNERS",
    "DroppedView",
    "drop_out_of_domain",
    "drop_outliers",
    "drop_thin_views",
    "max_corner_angle",
    "prepare_views",
    "require_views",
]

F64 = NDArray[np.float64]

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


def drop_thin_views(
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


def require_views(views: list[int], min_views: int, dropped: list[DroppedView]) -> None:
    """CalibrationFailed, naming the first views dropped and why, unless ``views`` holds at
    least ``min_views``."""
    if len(views) >= min_views:
        return
    reasons = "; ".join(f"{d.name}: {d.reason}" for d in dropped[:5])
    more = f" (+{len(dropped) - 5} more)" if len(dropped) > 5 else ""
    raise CalibrationFailed(
        f"only {len(views)} usable view(s), need at least {min_views}"
        + (f" — {reasons}{more}" if reasons else "")
    )


def drop_outliers(
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
    require_views([views[k] for k in keep], min_views, dropped)
    return [views[k] for k in keep], {views[k]: stage.T_ref_board[k] for k in keep}


def max_corner_angle(poses: dict[int, F64], X: dict[int, F64], views: list[int]) -> float:
    """Largest angle (rad) of a board corner off the optical axis over the views."""
    best = 0.0
    for i in views:
        p = X[i] @ poses[i][:3, :3].T + poses[i][:3, 3]
        cos = p[:, 2] / np.linalg.norm(p, axis=1)
        best = max(best, float(np.arccos(np.clip(cos, -1.0, 1.0)).max()))
    return best


def drop_out_of_domain(
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
