"""The left-right check's second search at half resolution (``stereo.lr_check_scale: 2``;
docs/stereo.md, "Left-right check at half resolution").

The exact search runs OpenCV's matcher twice: on the left view, and on the mirrored pair for the
left-right check. Here the mirrored pair's run searches the pair at 1/2 resolution
(:func:`rig.coarse_to_fine.downsample`, 2×2 block means) over the whole range, with the coarse
level's stiffer smoothness penalty (:meth:`rig.stereo.StereoParams.check_level`), a quarter of
the pixels and half the disparities. Its disparities, times 2, are interpolated back to full
resolution (bilinear; none where any of the four coarse pixels it interpolates has none) and
stand in for the full-resolution run's in :meth:`rig.stereo.StereoMatcher.disparity_of`. The
left view, and so every depth value served, is the exact search's; the check stays an
independent search of the other view, which is what removes a repetitive texture's wrong period.
"""

from __future__ import annotations

from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from rig.coarse_to_fine import downsample
from rig.disparity import SeenColumns

__all__ = ["HalfViewMatcher", "half_mirrored_view", "upsampled_mirrored"]

U8 = NDArray[np.uint8]
I16 = NDArray[np.int16]


class HalfViewMatcher(Protocol):
    """What the check needs of its matcher (a :class:`rig.stereo.StereoMatcher` of
    :meth:`rig.stereo.StereoParams.check_level`)."""

    def mirrored_view(self, left: U8, right: U8, seen: SeenColumns | None = None) -> tuple[I16, int]: ...

    def remove_speckles(self, fixed: I16) -> None: ...


def upsampled_mirrored(coarse: I16, coarse_min: int, shape: tuple[int, int], invalid: int) -> I16:
    """A mirrored half-resolution fixed-point disparity (h, w) (1/16 coarse px; invalid below
    ``coarse_min`` px) as the full-resolution mirrored view of a pair of ``shape`` (H, W): twice
    the disparity, interpolated bilinearly, ``invalid`` wherever an invalid coarse pixel takes
    part. The coarse images were padded on the right to an even size, so, mirrored, the padding
    is on the left: coarse column j covers full mirrored columns 2j − pad and 2j + 1 − pad."""
    field = coarse.astype(np.float32)
    field *= np.float32(2.0)
    np.copyto(field, np.float32(np.nan), where=coarse < coarse_min * 16)  # spread by the weights
    size = (coarse.shape[1] * 2, coarse.shape[0] * 2)
    up = np.asarray(cv2.resize(field, size, interpolation=cv2.INTER_LINEAR), dtype=np.float32)
    pad = size[0] - shape[1]
    up = up[: shape[0], pad:]
    # In place with OpenCV's NaN patch, not numpy's boolean indexing: this is on every frame.
    np.rint(up, out=up)
    cv2.patchNaNs(up, float(invalid))
    return up.astype(np.int16)


def half_mirrored_view(
    matcher: HalfViewMatcher, coarse_min: int, pair: tuple[U8, U8], seen: SeenColumns | None, invalid: int
) -> tuple[I16, int]:
    """The mirrored view of a pair of gray images (H, W) searched at half resolution by
    ``matcher`` (its smallest disparity ``coarse_min``), as full-resolution fixed point
    (``invalid`` where none), and the right image's first column it never matched."""
    left, right = pair
    halved = None if seen is None else seen.at_scale(2)
    fixed, unsearched = matcher.mirrored_view(downsample(left, 2), downsample(right, 2), halved)
    matcher.remove_speckles(fixed)
    full = upsampled_mirrored(fixed, coarse_min, (left.shape[0], left.shape[1]), invalid)
    # The first full column of the unmatched band takes part in the blend with it: unmatched too.
    return full, min(left.shape[1], 2 * unsearched - 1)
