"""The live service's temporal prior: what a search found on the last frames serves again where
the images have not changed since.

- **The coarse-to-fine search** (:mod:`rig.coarse_to_fine`, :class:`TemporalPrior`): row bands
  of the coarse level whose images have not changed since their last search keep that search's
  coarse disparities, and only the changed bands are searched again. The fine level always runs
  on the whole frame: the prior only says where to look.
- **The exact search** (:class:`LastSearch`): a pair in which no band changed since the last
  search keeps that search's disparities whole (OpenCV's SGBM in row bands would not give the
  whole frame's answer, and costs more than the whole frame per row), and any changed band
  searches the whole frame again.

Change is measured on the images averaged over 2×2 blocks (the coarse level's own for the
coarse-to-fine search) against the images each band was last *searched* on, not the previous
frame, so a slow drift adds up until it counts. A band has changed when at least
:data:`MIN_CHANGED` of its pixels differ by more than :data:`THRESHOLD` grey levels in either
image; when half of all pixels differ by more than half that (the light or the exposure changed,
the view moved, or the noise is too high to tell), the whole frame is searched. A changed band is
searched with its neighbours (an object straddles bands; the matcher's paths need context), and
every band is searched again at least every :data:`MAX_AGE` frames (in turn; the exact search's
whole frame at once).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from rig.disparity import UnfilteredDisparity

__all__ = [
    "BAND_ROWS",
    "MAX_AGE",
    "MIN_CHANGED",
    "THRESHOLD",
    "CoarseSearch",
    "LastSearch",
    "TemporalPrior",
    "changed_bands",
]

U8 = NDArray[np.uint8]
F32 = NDArray[np.float32]

#: Coarse rows per band.
BAND_ROWS = 8
#: Grey levels of the coarse images (2×2 or 4×4 means) a pixel must change by to count.
THRESHOLD = 8
#: Changed pixels that make a band changed.
MIN_CHANGED = 4
#: Frames after which a band is searched again anyway.
MAX_AGE = 30


@dataclass
class CoarseSearch:
    """The coarse level's disparities (h, w) float32 coarse px, NaN invalid: the left view's and
    the mirrored pair's (None without the left-right check), and the right image's first coarse
    column the mirrored search never reached."""

    left: F32
    mirrored: F32 | None
    right_unsearched_from: int


class TemporalPrior:
    """The coarse level's memory across frames (see the module doc); one per stream of frames,
    called in frame order. :attr:`searched_fraction` is the share of the last frame's coarse rows
    that were searched."""

    def __init__(self) -> None:
        self._left: U8 | None = None
        self._right: U8 | None = None
        self._search: CoarseSearch | None = None
        self._age = np.zeros(0, dtype=np.int64)
        self.searched_fraction = 1.0

    def reset(self) -> None:
        self._left = self._right = self._search = None

    def spans(self, left: U8, right: U8) -> list[tuple[int, int]]:
        """The coarse rows ``[a, b)`` to search for this frame's coarse images (all of them
        without a usable history)."""
        h = left.shape[0]
        if self._left is None or self._right is None or self._left.shape != left.shape:
            return [(0, h)]
        changed = changed_bands(left, right, self._left, self._right)
        if changed is None:
            return [(0, h)]
        changed |= self._age >= MAX_AGE
        near = changed.copy()
        near[1:] |= changed[:-1]
        near[:-1] |= changed[1:]
        return _runs(near, h)

    def merge(
        self, left: U8, right: U8, spans: list[tuple[int, int]], fresh: list[CoarseSearch]
    ) -> CoarseSearch:
        """This frame's coarse search: ``fresh`` (the searches of ``spans``, rows ``[a, b)``
        each) over the history; remembered, with the images, for the next frame."""
        h = left.shape[0]
        if spans == [(0, h)]:
            merged = fresh[0]
            self._left, self._right = left.copy(), right.copy()
            bands = -(-h // BAND_ROWS)
            # Staggered ages: the bands' scheduled searches come one after another.
            self._age = np.arange(bands, dtype=np.int64) % MAX_AGE
        else:
            assert self._search is not None and self._left is not None and self._right is not None
            merged = CoarseSearch(
                self._search.left.copy(),
                None if self._search.mirrored is None else self._search.mirrored.copy(),
                self._search.right_unsearched_from,
            )
            self._age += 1
            for (a, b), part in zip(spans, fresh, strict=True):
                merged.left[a:b] = part.left
                if merged.mirrored is not None and part.mirrored is not None:
                    merged.mirrored[a:b] = part.mirrored
                self._left[a:b] = left[a:b]
                self._right[a:b] = right[a:b]
                self._age[a // BAND_ROWS : -(-b // BAND_ROWS)] = 0
        self._search = merged
        self.searched_fraction = sum(b - a for a, b in spans) / h
        return merged


def changed_bands(left: U8, right: U8, last_left: U8, last_right: U8) -> NDArray[np.bool_] | None:
    """Per band of :data:`BAND_ROWS` rows of ``left``/``right`` (h, w) whether it changed since
    ``last_left``/``last_right`` (the module doc); None where the whole frame did."""
    diff = cv2.max(cv2.absdiff(left, last_left), cv2.absdiff(right, last_right))
    counts = np.bincount(diff.ravel(), minlength=256)
    if np.cumsum(counts)[THRESHOLD // 2] < diff.size / 2:
        # Half the pixels changed by more than half the threshold: the light, the exposure or
        # the whole view changed (or the noise is too high to tell).
        return None
    h = left.shape[0]
    bands = -(-h // BAND_ROWS)
    padded = np.zeros((bands * BAND_ROWS, left.shape[1]), dtype=bool)
    padded[:h] = diff > THRESHOLD
    changed: NDArray[np.bool_] = padded.reshape(bands, -1).sum(axis=1) >= MIN_CHANGED
    return changed


class LastSearch:
    """The exact search's memory across frames (the module doc): one per stream of frames,
    called in frame order with each frame's images halved (:func:`rig.coarse_to_fine.downsample`).
    :attr:`searched_fraction` is 1.0 when the last frame was searched, 0.0 when it kept the last
    search."""

    def __init__(self) -> None:
        self._left: U8 | None = None
        self._right: U8 | None = None
        self._kept: UnfilteredDisparity | None = None
        self._age = 0
        self.searched_fraction = 1.0

    def kept(self, left: U8, right: U8) -> UnfilteredDisparity | None:
        """A copy of the last search's disparities when no band of these images changed since
        it and it is younger than :data:`MAX_AGE` frames; else None: search, then
        :meth:`remember`."""
        if self._kept is None or self._left is None or self._right is None or self._left.shape != left.shape:
            return None
        if self._age + 1 >= MAX_AGE:
            return None
        changed = changed_bands(left, right, self._left, self._right)
        if changed is None or changed.any():
            return None
        self._age += 1
        self.searched_fraction = 0.0
        return _copied(self._kept)

    def remember(self, left: U8, right: U8, found: UnfilteredDisparity) -> None:
        """This frame's images and search (a copy: the search's user filters it in place)."""
        self._left, self._right = left.copy(), right.copy()
        self._kept = _copied(found)
        self._age = 0
        self.searched_fraction = 1.0


def _copied(found: UnfilteredDisparity) -> UnfilteredDisparity:
    """``found`` with its arrays copied (its other fields as they are)."""
    mirrored = None if found.mirrored is None else found.mirrored.copy()
    normalised = found.normalised and (found.normalised[0].copy(), found.normalised[1].copy())
    return replace(found, left=found.left.copy(), mirrored=mirrored, normalised=normalised)


def _runs(bands: NDArray[np.bool_], height: int) -> list[tuple[int, int]]:
    """The row spans of the runs of True bands, clipped to ``height``."""
    out = []
    edges = np.flatnonzero(np.diff(np.concatenate(([0], bands.view(np.int8), [0]))))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        out.append((int(start) * BAND_ROWS, min(height, int(stop) * BAND_ROWS)))
    return out
