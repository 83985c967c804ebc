"""How far the rectified pair is from rectified: the vertical disparity of matched features
(docs/rectification.md).

Each match's two rays are rotated into their VPCs (``R_cam_rect``) and projected by the pair's
pinhole; the vertical disparity is the row difference ``v_left − v_right`` in VPC pixels, over
the matches that land inside both VPC images. A perfect calibration leaves only the matcher's
noise; a rotation error of a tenth of a degree gives about half a pixel at 640×480, 90°.

Never a false alarm: fewer than ``min_matches`` matches inside the pair, or matches bunched in
a few places (``spread``, the share of a 3×3 grid over the image with at least three matches,
below ``min_spread``), is the state ``"not enough matches"``, not a measurement.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from rig.rectified import RectifiedPair

__all__ = ["MeasureState", "VerticalDisparity", "rectified_rows", "vertical_disparity"]

F64 = NDArray[np.float64]

MeasureState = Literal["ok", "not enough matches"]
_GRID = 3
_PER_CELL = 3


@dataclass(frozen=True)
class VerticalDisparity:
    """``count`` matches inside both VPC images; ``p50_px`` / ``p95_px`` percentiles of
    ``|v_left − v_right|`` and ``median_px`` of the signed difference (None unless ``state`` is
    ``"ok"``); ``spread`` in [0, 1]; ``reason`` says why there is no measurement."""

    count: int
    p50_px: float | None
    p95_px: float | None
    median_px: float | None
    spread: float
    state: MeasureState
    reason: str | None = None

    @property
    def ok(self) -> bool:
        return self.state == "ok"


def rectified_rows(pair: RectifiedPair, name: str, rays: F64) -> tuple[F64, NDArray[np.bool_]]:
    """Pixels (N, 2) of camera ``name``'s rays (N, 3, its frame) in its VPC, and which lie inside
    the VPC image."""
    in_rect = np.asarray(rays, dtype=np.float64).reshape(-1, 3) @ pair.R_cam_rect[name]
    return pair.camera.project(in_rect)


def vertical_disparity(
    pair: RectifiedPair, rays_left: F64, rays_right: F64, *, min_matches: int = 50, min_spread: float = 0.4
) -> VerticalDisparity:
    """The vertical disparity of matched rays (N, 3) of ``pair.left`` / ``pair.right`` (see the
    module doc)."""
    pl, ok_l = rectified_rows(pair, pair.left, rays_left)
    pr, ok_r = rectified_rows(pair, pair.right, rays_right)
    inside = ok_l & ok_r
    n = int(np.count_nonzero(inside))
    cam = pair.camera
    cells = np.zeros((_GRID, _GRID), dtype=np.int64)
    if n:
        cu = np.clip((pl[inside, 0] / cam.width * _GRID).astype(int), 0, _GRID - 1)
        cv = np.clip((pl[inside, 1] / cam.height * _GRID).astype(int), 0, _GRID - 1)
        np.add.at(cells, (cv, cu), 1)
    spread = float(np.count_nonzero(cells >= _PER_CELL)) / cells.size
    if n < min_matches or spread < min_spread:
        why = (
            f"{n} matches in the rectified pair, need {min_matches}"
            if n < min_matches
            else f"matches cover {spread:.0%} of the rectified pair, need {min_spread:.0%}"
        )
        return VerticalDisparity(n, None, None, None, spread, "not enough matches", why)
    dv = pl[inside, 1] - pr[inside, 1]
    a = np.abs(dv)
    return VerticalDisparity(
        n, float(np.percentile(a, 50)), float(np.percentile(a, 95)), float(np.median(dv)), spread, "ok"
    )
