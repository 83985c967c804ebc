"""What a stereo matcher hands on (:mod:`rig.stereo`, :mod:`rig.coarse_to_fine`): the columns each
lens sees, the fixed-point disparities before speckle removal, the disparity in pixels."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["MatchedDisparity", "SeenColumns", "UnfilteredDisparity"]

F32 = NDArray[np.float32]


@dataclass
class MatchedDisparity:
    """The disparity of one matched pair: (H, W) float32 px, NaN where ``valid`` is False."""

    disparity: F32
    valid: NDArray[np.bool_]


@dataclass(frozen=True)
class SeenColumns:
    """The columns ``[start, stop)`` of each rectified image that its lens sees on at least one
    row (a lat-lon field's corners are outside a lens). The matcher never matches a reference
    pixel outside them, so it leaves out the columns that only serve those pixels."""

    left: tuple[int, int]
    right: tuple[int, int]

    @classmethod
    def of(cls, left_valid: NDArray[np.bool_], right_valid: NDArray[np.bool_]) -> SeenColumns:
        """From the two lookup tables' validity masks (H, W)."""
        return cls(_span(left_valid), _span(right_valid))

    def at_scale(self, scale: int) -> SeenColumns:
        """The same columns at 1/``scale`` resolution (2×2 or ``scale``² block means): a coarse
        column is seen when any of its full-resolution columns is."""

        def span(cols: tuple[int, int]) -> tuple[int, int]:
            return cols[0] // scale, -(-cols[1] // scale)

        return SeenColumns(span(self.left), span(self.right))


def _span(valid: NDArray[np.bool_]) -> tuple[int, int]:
    cols = np.flatnonzero(valid.any(axis=0))
    return (int(cols[0]), int(cols[-1]) + 1) if cols.size else (0, 0)


@dataclass
class UnfilteredDisparity:
    """OpenCV's fixed-point disparities of one pair (1/16 px, int16) before the speckle removal:
    the left view's (H, W) and, with ``lr_check``, the mirrored pair's (H, W), still mirrored;
    ``right_unsearched_from``: the right image's columns from this one on have no right-view
    disparity (the mirrored run's unmatched band). Made by :meth:`StereoMatcher.compute`,
    turned into a :class:`MatchedDisparity` by :meth:`StereoMatcher.disparity_of`."""

    left: NDArray[np.int16]
    mirrored: NDArray[np.int16] | None = None
    right_unsearched_from: int = 0
    #: Both images' local contrast normalisation (:func:`rig.subpixel.normalise_contrast`) when
    #: the matcher made it (the coarse-to-fine search does): the refinement need not make it again.
    normalised: tuple[F32, F32] | None = None
    #: The resolution the mirrored pair was searched at: 1 (full) or 2 (half: rig.half_check).
    check_scale: int = 1
