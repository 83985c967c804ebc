"""Disparity post-filters (docs/stereo.md, "Filters"), each switched by :class:`rig.stereo.StereoParams`.

All work on disparity images (H, W) float32 in px with NaN where invalid and a matching bool
mask; none fills holes (a filter may only remove or smooth values, never invent them).
Speckle removal is the matcher's own (``speckle_size``/``speckle_range``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = [
    "TemporalFilter",
    "copy_where",
    "fill_where",
    "index_map",
    "left_right_consistent",
    "median_filter",
    "visible_in_right",
]

F32 = NDArray[np.float32]
Mask = NDArray[np.bool_]
_Pixel = TypeVar("_Pixel", np.uint8, np.float32)


# Read-only images the filters reuse on every frame (constants for fill_where, keyed by the
# value's bit pattern so that NaN is a key like any other; row indices for cv2.remap), each grown
# to the largest size asked for; smaller ones are views of them.
_images: dict[object, F32] = {}


def _reused_image(key: object, shape: tuple[int, ...], make: Callable[[tuple[int, int]], F32]) -> F32:
    """``make(size)`` cached under ``key`` and kept read-only, viewed at ``shape`` (H, W)."""
    h, w = shape
    img = _images.get(key)
    if img is None or img.shape[0] < h or img.shape[1] < w:
        img = make((h, w) if img is None else (max(h, img.shape[0]), max(w, img.shape[1])))
        img.flags.writeable = False
        _images[key] = img  # threads racing here each make one: harmless
    return img[:h, :w]


def _constant_image(shape: tuple[int, ...], value: float) -> F32:
    """A read-only float32 image of ``value`` and ``shape`` (H, W)."""
    bits = int(np.float32(value).view(np.uint32))
    return _reused_image(bits, shape, lambda size: np.full(size, bits, dtype=np.uint32).view(np.float32))


def index_map(shape: tuple[int, ...], axis: int) -> F32:
    """Each pixel's row (``axis`` 0: the y map of a remap along rows) or column (1) index,
    float32 (H, W), read-only (reused from frame to frame)."""

    def make(size: tuple[int, int]) -> F32:
        index = np.arange(size[axis], dtype=np.float32)
        return np.broadcast_to(index[:, None] if axis == 0 else index[None, :], size).copy()

    return _reused_image(("index", axis), shape, make)


def copy_where(dst: F32, src: F32, where: Mask) -> None:
    """``dst[where] = src[where]`` in place for (H, W) float32 arrays (views are fine).

    OpenCV's masked copy: on a 640×480 frame in cache it costs ~0.03 ms where numpy's boolean
    assignment, ``np.copyto`` or ``np.where`` cost 0.1-0.2 ms (they branch per pixel), and the
    post-processing stage does this on every frame."""
    if cv2.copyTo(src, where.view(np.uint8), dst) is not dst:  # OpenCV made a new array instead
        raise ValueError(f"copy_where: cannot write {src.dtype} {src.shape} into {dst.dtype} {dst.shape}")


def fill_where(dst: F32, value: float, where: Mask) -> None:
    """``dst[where] = value`` in place for (H, W) float32 ``dst`` (:func:`copy_where` from a
    cached constant image)."""
    copy_where(dst, _constant_image(dst.shape, value), where)


def _match_columns(disparity: F32, valid: Mask) -> F32:
    """``x - d``: the column of each left pixel's match in the right image (float32 (H, W),
    ``x`` itself where invalid)."""
    x = index_map(disparity.shape, 1)
    columns = np.subtract(x, disparity, dtype=np.float32)
    # OpenCV's masked copy, not np.where: this runs twice on every frame.
    copy_where(columns, x, ~valid)
    return columns


def _at_match(image: NDArray[_Pixel], columns: F32) -> NDArray[_Pixel]:
    """``image[y, clip(round(columns[y, x]))]`` (H, W): the right image's value at each left
    pixel's match. OpenCV's nearest-neighbour remap rounds like ``np.rint`` and replicates the
    border like a clip, at a fraction of ``np.take_along_axis``'s cost (it is on every frame)."""
    out = cv2.remap(
        image, columns, index_map(columns.shape, 0), cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE
    )
    return np.asarray(out, dtype=image.dtype)


def left_right_consistent(
    left_disp: F32, valid: Mask, right_disp: F32, max_diff: float, right_blind_from: int | None = None
) -> Mask:
    """True where the right image's disparity at the matched column agrees within ``max_diff``
    px (both (H, W) float32, NaN invalid). Occluded and mismatched pixels fail.

    ``right_blind_from``: right-image columns from this one on were never searched by the
    right-view matcher (its unmatched border band); matches landing there have no evidence
    either way and pass.
    """
    columns = _match_columns(left_disp, valid)
    dr = _at_match(right_disp, columns)
    with np.errstate(invalid="ignore"):
        agree = np.abs(left_disp - dr) <= max_diff
    if right_blind_from is not None:
        agree |= np.rint(columns) >= right_blind_from
    inside = columns >= -0.5
    out: Mask = valid & agree & inside
    return out


def visible_in_right(disparity: F32, valid: Mask, right_lut_valid: Mask) -> Mask:
    """``valid`` and the matched right VPC pixel lies where the right LUT is valid."""
    seen = _at_match(right_lut_valid.view(np.uint8), _match_columns(disparity, valid))
    out: Mask = valid & seen.view(np.bool_)
    return out


def median_filter(disparity: F32, valid: Mask, ksize: int) -> tuple[F32, Mask]:
    """``ksize`` 3 or 5 median of valid disparities; pixels whose window is mostly invalid
    become invalid. ``disparity`` is NaN exactly where ``valid`` is False (the module's
    convention: the NaNs are what marks the invalid pixels here). Returns (disparity, valid),
    NaN invalid."""
    if ksize not in (3, 5):
        raise ValueError(f"median ksize must be 3 or 5, got {ksize}")
    src = disparity.astype(np.float32)  # a copy
    cv2.patchNaNs(src, -np.inf)  # invalid pixels sort below every disparity
    med: F32 = np.asarray(cv2.medianBlur(src, ksize), dtype=np.float32)
    # NaN where invalid (0·NaN) and where the window was mostly invalid (0·(−inf)), exact
    # elsewhere: cheaper than masking.
    cv2.scaleAdd(disparity, 0.0, med, dst=med)
    cv2.scaleAdd(med, 0.0, med, dst=med)
    ok = ~np.isnan(med)
    ok &= valid
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

    @property
    def state(self) -> F32 | None:
        """The history: the last output (None before the first frame or after :meth:`clear`).
        Setting it carries a history over from another filter (the frames before a chunk)."""
        return self._state

    @state.setter
    def state(self, value: F32 | None) -> None:
        self._state = None if value is None else np.array(value, dtype=np.float32)

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
        fill_where(out, np.nan, ~valid)
        self._state = out
        return out
