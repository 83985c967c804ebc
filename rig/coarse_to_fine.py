"""The coarse-to-fine disparity search (docs/stereo.md, "Coarse-to-fine search"), the default
matcher of :class:`rig.stereo.StereoMatcher` (``stereo.coarse_to_fine``).

1. **Coarse level**: both images averaged over ``scale``² blocks (OpenCV's area resampling), then
   OpenCV's matcher over the whole disparity range at that resolution, left view and (with the
   left-right check) the mirrored pair, with a stiffer smoothness penalty
   (:meth:`rig.stereo.StereoParams.coarse_level`). Its disparities, speckles removed, times
   ``scale``, are the hypotheses of
2. **the fine level** (:mod:`rig.band_search`): block matching at full resolution around three
   per-pixel hypotheses: the coarse field upsampled (bilinear), ±1 px; the smallest and the
   largest coarse disparity of the pixel's 3×3 coarse neighbourhood (nearest), which at a depth
   edge are the two sides' disparities (the bilinear field blurs them into a value of neither)
   and at the rim of the coarse result extend it by a coarse pixel. Both views, so that the
   full-resolution left-right check, the subpixel refinement, the filters and the confidence
   after it (:meth:`rig.stereo.StereoMatcher.disparity_of`, :mod:`rig.postprocess`) run as on
   the exact search's output, which this has the format of (OpenCV's fixed point).

In the live service (``stereo.temporal_prior``) the coarse level searches only the row bands
whose images changed since their last search (:mod:`rig.temporal_prior`).
"""

from __future__ import annotations

from concurrent.futures import Executor, Future
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from rig.band_search import BAND_ROWS, Hypothesis, quantise_normalised, search_rows
from rig.bands import submit_or_run
from rig.disparity import SeenColumns, UnfilteredDisparity
from rig.subpixel import Normalisation
from rig.temporal_prior import CoarseSearch, TemporalPrior

__all__ = ["CoarseMatcher", "CoarseToFine", "FineLevel", "downsample", "hypotheses"]

U8 = NDArray[np.uint8]
I16 = NDArray[np.int16]
F32 = NDArray[np.float32]

#: Coarse rows of context above and below a band the temporal prior searches again.
PRIOR_MARGIN_ROWS = 16


class CoarseMatcher(Protocol):
    """What the coarse level needs of its matcher (a :class:`rig.stereo.StereoMatcher` of the
    coarse parameters)."""

    def compute(self, left: U8, right: U8, seen: SeenColumns | None = None) -> UnfilteredDisparity: ...

    def remove_speckles(self, fixed: I16) -> None: ...


@dataclass(frozen=True)
class FineLevel:
    """The search's figures: the coarse level's ``scale`` and smallest disparity (coarse px),
    the full resolution's block ``window``, disparity bounds ``[d_min, d_max]`` and fixed-point
    value of an invalid pixel; ``lr_check``: search the right view too; ``parabola``: subpixel
    offsets (else whole pixels, for a refinement that follows)."""

    scale: int
    coarse_min: int
    window: int
    d_min: int
    d_max: int
    invalid: int
    lr_check: bool
    parabola: bool


def downsample(image: U8, scale: int) -> U8:
    """``image`` (H, W) averaged over ``scale``² blocks ((H, W) padded up to multiples of
    ``scale`` by repeating its last row and column): coarse pixel (i, j) is full pixels
    ``[s·i, s·i + s)`` × ``[s·j, s·j + s)``."""
    h, w = image.shape
    pad_h, pad_w = -h % scale, -w % scale
    if pad_h or pad_w:
        image = cv2.copyMakeBorder(image, 0, pad_h, 0, pad_w, cv2.BORDER_REPLICATE)
    size = ((w + pad_w) // scale, (h + pad_h) // scale)
    return np.asarray(cv2.resize(image, size, interpolation=cv2.INTER_AREA), dtype=np.uint8)


def _upsampled(coarse: F32, shape: tuple[int, int], scale: int, interpolation: int) -> F32:
    """A coarse field at full resolution (H, W) in full-resolution pixels (× ``scale``)."""
    size = (coarse.shape[1] * scale, coarse.shape[0] * scale)
    up = np.asarray(cv2.resize(coarse, size, interpolation=interpolation), dtype=np.float32)
    out = np.ascontiguousarray(up[: shape[0], : shape[1]])
    out *= np.float32(scale)
    return out


def hypotheses(coarse: F32, shape: tuple[int, int], scale: int) -> list[Hypothesis]:
    """The fine level's hypotheses (module doc) from a coarse disparity (h, w) float32 coarse
    px, NaN invalid, for a full-resolution image of ``shape``."""
    up = _upsampled(coarse, shape, scale, cv2.INTER_LINEAR)
    nearest = _upsampled(coarse, shape, scale, cv2.INTER_NEAREST)
    # Next to an invalid coarse pixel the bilinear field is NaN: the nearest one's value there.
    gap = np.isnan(up)
    up[gap] = nearest[gap]
    box = np.ones((3, 3), np.uint8)
    invalid = np.isnan(coarse)
    low = np.where(invalid, np.float32(np.inf), coarse)
    low = np.asarray(cv2.erode(low, box, borderType=cv2.BORDER_REPLICATE), dtype=np.float32)
    low[np.isinf(low)] = np.nan
    high = np.where(invalid, np.float32(-np.inf), coarse)
    high = np.asarray(cv2.dilate(high, box, borderType=cv2.BORDER_REPLICATE), dtype=np.float32)
    high[np.isinf(high)] = np.nan
    return [
        Hypothesis(up, 1),
        Hypothesis(_upsampled(low, shape, scale, cv2.INTER_NEAREST), 0),
        Hypothesis(_upsampled(high, shape, scale, cv2.INTER_NEAREST), 0),
    ]


def _coarse_seen(seen: SeenColumns | None, scale: int) -> SeenColumns | None:
    if seen is None:
        return None

    def span(cols: tuple[int, int]) -> tuple[int, int]:
        return cols[0] // scale, -(-cols[1] // scale)

    return SeenColumns(span(seen.left), span(seen.right))


class CoarseToFine:
    """The search (module doc) with the ``coarse`` level's matcher and the ``level``'s figures.
    Not safe for concurrent calls (the matcher's scratch buffers, the temporal prior)."""

    def __init__(self, coarse: CoarseMatcher, level: FineLevel) -> None:
        self.coarse = coarse
        self.level = level
        self.prior = TemporalPrior()

    def compute(
        self,
        left: U8,
        right: U8,
        seen: SeenColumns | None = None,
        *,
        pool: Executor | None = None,
        temporal_prior: bool = False,
    ) -> UnfilteredDisparity:
        """Fixed-point disparities of gray images (H, W) uint8 as
        :meth:`rig.stereo.StereoMatcher.compute` gives them (with ``lr_check`` the mirrored
        pair's too), and both images' contrast normalisation. ``pool``: threads for the
        normalisation and the fine level's bands; ``temporal_prior``: the live service's
        (frames in order, one stream)."""
        lv = self.level
        normalised = Normalisation(left, right, pool)
        coarse_left, coarse_right = downsample(left, lv.scale), downsample(right, lv.scale)
        if temporal_prior:
            found = self._with_prior(coarse_left, coarse_right, _coarse_seen(seen, lv.scale))
        else:
            self.prior.reset()
            found = self._search(coarse_left, coarse_right, _coarse_seen(seen, lv.scale))
        norm_left, norm_right = normalised.result()
        ref, other = quantise_normalised(norm_left), quantise_normalised(norm_right)
        shape = (left.shape[0], left.shape[1])
        views = [(ref, other, hypotheses(found.left, shape, lv.scale))]
        if found.mirrored is not None:
            mirrored = (np.ascontiguousarray(other[:, ::-1]), np.ascontiguousarray(ref[:, ::-1]))
            views.append((*mirrored, hypotheses(found.mirrored, shape, lv.scale)))
        fixed = self._fine(views, pool)
        unsearched = min(left.shape[1], lv.scale * found.right_unsearched_from)
        return UnfilteredDisparity(
            fixed[0], fixed[1] if len(fixed) > 1 else None, unsearched, (norm_left, norm_right)
        )

    def _search(self, left: U8, right: U8, seen: SeenColumns | None) -> CoarseSearch:
        """The coarse level's matcher on coarse images, speckles removed, in coarse px."""
        raw = self.coarse.compute(left, right, seen)
        mirrored = None if raw.mirrored is None else self._pixels(raw.mirrored)
        return CoarseSearch(self._pixels(raw.left), mirrored, raw.right_unsearched_from)

    def _pixels(self, fixed: I16) -> F32:
        self.coarse.remove_speckles(fixed)
        out = fixed.astype(np.float32)
        out *= np.float32(1.0 / 16.0)
        out[fixed < self.level.coarse_min * 16] = np.nan
        return out

    def _with_prior(self, left: U8, right: U8, seen: SeenColumns | None) -> CoarseSearch:
        """The coarse search of the rows the temporal prior says changed, over its history."""
        h = left.shape[0]
        spans = self.prior.spans(left, right)
        fresh = []
        for a, b in spans:
            if (a, b) == (0, h):
                fresh.append(self._search(left, right, seen))
                continue
            # Rows of context above and below: the matcher's paths run through them.
            top, bottom = max(0, a - PRIOR_MARGIN_ROWS), min(h, b + PRIOR_MARGIN_ROWS)
            part = self._search(left[top:bottom], right[top:bottom], seen)
            keep = slice(a - top, b - top)
            mirrored = None if part.mirrored is None else part.mirrored[keep]
            fresh.append(CoarseSearch(part.left[keep], mirrored, part.right_unsearched_from))
        return self.prior.merge(left, right, spans, fresh)

    def _fine(self, views: list[tuple[U8, U8, list[Hypothesis]]], pool: Executor | None) -> list[I16]:
        """The fine level of each view (reference, other, hypotheses), in row bands on ``pool``."""
        lv = self.level
        outputs = [np.empty(ref.shape, dtype=np.int16) for ref, _, _ in views]
        futures: list[Future[None]] = []

        def band(view: int, r0: int, r1: int) -> None:
            ref, other, hyps = views[view]
            outputs[view][r0:r1] = search_rows(
                ref,
                other,
                hyps,
                (r0, r1),
                window=lv.window,
                d_range=(lv.d_min, lv.d_max),
                invalid=lv.invalid,
                parabola=lv.parabola,
            )

        height = views[0][0].shape[0]
        for view in range(len(views)):
            for r0 in range(0, height, BAND_ROWS):
                futures.append(submit_or_run(pool, band, view, r0, min(height, r0 + BAND_ROWS)))
        for future in futures:
            future.result()
        return outputs
