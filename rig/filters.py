"""Disparity post-filters (DESIGN §6), each switched by :class:`rig.stereo.StereoParams`.

All work on disparity images (H, W) float32 in px with NaN where invalid and a matching bool
mask; none fills holes (a filter may only remove or smooth values, never invent them).
Speckle removal is the matcher's own (``speckle_size``/``speckle_range``).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = [
    "TemporalFilter",
    "left_right_consistent",
    "median_filter",
    "visible_in_right",
]

F32 = NDArray[np.float32]
Mask = NDArray[np.bool_]

# Stand-in for invalid pixels inside the median: far below any disparity, so a window whose
# majority is invalid yields it (and stays invalid) and a minority cannot drag values far.
_INVALID_FILL = np.float32(-1.0e6)


def _right_columns(disparity: F32, valid: Mask) -> NDArray[np.intp]:
    """Column ``round(x - d)`` of each left pixel's match in the right image, clipped (H, W)."""
    w = disparity.shape[1]
    x = np.arange(w, dtype=np.float32)[None, :]
    cols = np.rint(x - np.where(valid, disparity, 0.0))
    return np.clip(cols, 0, w - 1).astype(np.intp)


def left_right_consistent(
    left_disp: F32, valid: Mask, right_disp: F32, max_diff: float, right_blind_from: int | None = None
) -> Mask:
    """True where the right image's disparity at the matched column agrees within ``max_diff``
    px (both (H, W) float32, NaN invalid). Occluded and mismatched pixels fail.

    ``right_blind_from``: right-image columns from this one on were never searched by the
    right-view matcher (its unmatched border band); matches landing there have no evidence
    either way and pass.
    """
    cols = _right_columns(left_disp, valid)
    dr = np.take_along_axis(right_disp, cols, axis=1)
    with np.errstate(invalid="ignore"):
        agree = np.abs(left_disp - dr) <= max_diff
    if right_blind_from is not None:
        agree |= cols >= right_blind_from
    x = np.arange(left_disp.shape[1])[None, :]
    inside = (x - np.where(valid, left_disp, 0.0)) >= -0.5
    out: Mask = valid & agree & inside
    return out


def visible_in_right(disparity: F32, valid: Mask, right_lut_valid: Mask) -> Mask:
    """``valid`` and the matched right VPC pixel lies where the right LUT is valid."""
    cols = _right_columns(disparity, valid)
    out: Mask = valid & np.take_along_axis(right_lut_valid, cols, axis=1)
    return out


def median_filter(disparity: F32, valid: Mask, ksize: int) -> tuple[F32, Mask]:
    """``ksize`` 3 or 5 median of valid disparities; pixels whose window is mostly invalid
    become invalid. Returns (disparity, valid), NaN invalid."""
    if ksize not in (3, 5):
        raise ValueError(f"median ksize must be 3 or 5, got {ksize}")
    src = np.where(valid, disparity, _INVALID_FILL).astype(np.float32)
    med: F32 = np.asarray(cv2.medianBlur(src, ksize), dtype=np.float32)
    ok = valid & (med > _INVALID_FILL / 2)
    med[~ok] = np.nan
    return med, ok


class TemporalFilter:
    """Exponential smoothing of disparity over frames, per pixel.

    ``out = α·previous + (1 − α)·new`` where both are valid and differ by at most ``reset`` px;
    elsewhere the new value passes unchanged (motion or new surfaces restart the average, so the
    filter never drags a moving edge). A pixel invalid in the new frame stays invalid: stale
    depth is never reported. Not thread-safe; one instance per stream.
    """

    def __init__(self, alpha: float, reset: float = 1.0) -> None:
        if not (0.0 <= alpha < 1.0):
            raise ValueError(f"temporal alpha must be in [0, 1), got {alpha}")
        self.alpha = float(alpha)
        self.reset = float(reset)
        self._state: F32 | None = None

    def clear(self) -> None:
        self._state = None

    def __call__(self, disparity: F32, valid: Mask) -> F32:
        """Smoothed disparity (H, W) float32, NaN where ``valid`` is False."""
        prev = self._state
        if prev is None or prev.shape != disparity.shape or self.alpha == 0.0:
            out = disparity.copy()
        else:
            with np.errstate(invalid="ignore"):
                blend = valid & (np.abs(prev - disparity) <= self.reset)
            a = np.float32(self.alpha)
            out = np.where(blend, a * prev + (np.float32(1.0) - a) * disparity, disparity).astype(np.float32)
        out[~valid] = np.nan
        self._state = out
        return out
