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
from typing import Any, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from rig.band_search import BAND_ROWS, NONE, HypothesesOf, Hypothesis, quantise_normalised, search_rows
from rig.bands import submit_or_run
from rig.disparity import SeenColumns, UnfilteredDisparity
from rig.subpixel import Normalisation, normalise_contrast
from rig.temporal_prior import CoarseSearch, TemporalPrior

__all__ = ["CoarseMatcher", "CoarseToFine", "FineLevel", "band_hypotheses", "downsample", "hypotheses"]

U8 = NDArray[np.uint8]
I16 = NDArray[np.int16]
F32 = NDArray[np.float32]

#: Coarse rows of context above and below a band the temporal prior searches again.
PRIOR_MARGIN_ROWS = 16


class CoarseMatcher(Protocol):
    """What the coarse level needs of its matcher (a :class:`rig.stereo.StereoMatcher` of the
    coarse parameters)."""

    def left_view(self, left: U8, right: U8, seen: SeenColumns | None = None) -> I16: ...

    def mirrored_view(self, left: U8, right: U8, seen: SeenColumns | None = None) -> tuple[I16, int]: ...

    def remove_speckles(self, fixed: I16) -> None: ...


@dataclass(frozen=True)
class FineLevel:
    """The search's figures: the coarse level's ``scale``, smallest disparity and disparities
    searched beyond the range (``beyond``; coarse px), the columns on the left it leaves
    unmatched (``blind``, full-resolution px: the fine levels leave them too), the full
    resolution's block ``window``, disparity bounds ``[d_min, d_max]`` and fixed-point value of
    an invalid pixel; ``lr_check``: search the right view too; ``parabola``: subpixel offsets
    (else whole pixels, for a refinement that follows); ``confirm``: the coarse level
    confirmed (:func:`_agreed`) and its hypotheses kept :data:`CONFIRM_INWARD` coarse px from
    its invalid pixels."""

    scale: int
    coarse_min: int
    beyond: int
    blind: int
    window: int
    d_min: int
    d_max: int
    invalid: int
    lr_check: bool
    parabola: bool
    confirm: bool = False


def downsample(image: U8, scale: int) -> U8:
    """``image`` (H, W) averaged over ``scale``² blocks ((H, W) padded up to multiples of
    ``scale`` by repeating its last row and column): coarse pixel (i, j) is full pixels
    ``[s·i, s·i + s)`` × ``[s·j, s·j + s)``."""
    h, w = image.shape
    pad_h, pad_w = -h % scale, -w % scale
    padded = cv2.copyMakeBorder(image, 0, pad_h, 0, pad_w, cv2.BORDER_REPLICATE) if pad_h or pad_w else image
    size = ((w + pad_w) // scale, (h + pad_h) // scale)
    return np.asarray(cv2.resize(padded, size, interpolation=cv2.INTER_AREA), dtype=np.uint8)


def _halved(image: U8, scale: int) -> U8:
    """``image`` downsampled by 2 until 1/``scale`` (as the search's pyramid)."""
    while scale > 1:
        image, scale = downsample(image, 2), scale // 2
    return image


def _upsampled(coarse: F32, shape: tuple[int, int], scale: int, interpolation: int) -> F32:
    """A coarse field at full resolution (H, W), still in coarse pixels."""
    size = (coarse.shape[1] * scale, coarse.shape[0] * scale)
    up = np.asarray(cv2.resize(coarse, size, interpolation=interpolation), dtype=np.float32)
    return np.ascontiguousarray(up[: shape[0], : shape[1]])  # OpenCV writes into it


def _centres(field: F32, scale: int) -> I16:
    """A field (H, W) of coarse px, ``NONE / scale`` where none, as whole full-resolution px:
    ``round(field · scale)`` saturated to int16 (:data:`NONE` where none)."""
    scaled: Any = cv2.multiply  # (a scalar factor: OpenCV's type stubs leave it out)
    return np.asarray(scaled(field, float(scale), dtype=cv2.CV_16S), dtype=np.int16)


def hypotheses(
    coarse: F32, shape: tuple[int, int], scale: int, inward: int | None = None
) -> list[Hypothesis]:
    """The fine level's hypotheses (module doc) from a coarse disparity (h, w) float32 coarse
    px, NaN invalid, for a full-resolution image of ``shape``. ``inward``: none where an invalid
    coarse pixel lies within that many coarse px (0: the pixel's own; the image's border does
    not count), so that the hypotheses do not extend the coarse result."""
    invalid = np.isnan(coarse)
    none = NONE / scale
    up = _upsampled(coarse, shape, scale, cv2.INTER_LINEAR)
    filled = coarse.copy()
    filled[invalid] = none
    # The bilinear field is NaN next to an invalid coarse pixel: the nearest value there.
    nearest = _upsampled(filled, shape, scale, cv2.INTER_NEAREST)
    cv2.copyTo(
        nearest, cv2.bitwise_not(cv2.compare(up, up, cv2.CMP_EQ)), up
    )  # (OpenCV's NE: NaN ≠ NaN is False)
    fields = [up]
    box = np.ones((3, 3), np.uint8)
    for pad, morph in ((np.inf, cv2.erode), (-np.inf, cv2.dilate)):
        padded = coarse.copy()
        padded[invalid] = pad
        extreme = np.asarray(morph(padded, box, borderType=cv2.BORDER_REPLICATE), dtype=np.float32)
        extreme[np.isinf(extreme)] = none  # no valid neighbour
        fields.append(_upsampled(extreme, shape, scale, cv2.INTER_NEAREST))
    centres = [_centres(f, scale) for f in fields]
    if inward is not None:
        box = np.ones((2 * inward + 1,) * 2, np.uint8)
        near = np.asarray(
            cv2.dilate(invalid.view(np.uint8), box, borderType=cv2.BORDER_CONSTANT, borderValue=0)
        )
        none_here = _upsampled(near.astype(np.float32), shape, scale, cv2.INTER_NEAREST) != 0
        for c in centres:
            c[none_here] = NONE
    return [Hypothesis(centres[0], 1), Hypothesis(centres[1], 0), Hypothesis(centres[2], 0)]


def band_hypotheses(
    coarse: F32, width: int, height: int, scale: int, inward: int | None = None
) -> HypothesesOf:
    """:func:`hypotheses` of a coarse field made for the rows asked for only (each band's on its
    own thread): from the coarse rows they come from and two more either side, so that they are
    the whole image's, bit for bit (the bilinear field and the 3×3 extremes reach one coarse
    row, ``inward`` as many: up to 2)."""

    def rows(a: int, b: int) -> list[Hypothesis]:
        c0, c1 = max(0, a // scale - 2), min(coarse.shape[0], -(-b // scale) + 2)
        top = c0 * scale
        part = hypotheses(coarse[c0:c1], (min(height, c1 * scale) - top, width), scale, inward)
        return [Hypothesis(h.centre[a - top : b - top], h.half_width) for h in part]

    return rows


class CoarseToFine:
    """The search (module doc) with the ``coarse`` level's matcher and the ``level``'s figures.
    Not safe for concurrent calls (the matcher's scratch buffers, the temporal prior)."""

    def __init__(self, coarse: tuple[CoarseMatcher, CoarseMatcher], level: FineLevel) -> None:
        if level.scale not in (2, 4):
            raise ValueError(f"coarse-to-fine: the coarse level is 1/2 or 1/4, not 1/{level.scale}")
        # A matcher per view, so that the two views' searches run at once (an OpenCV matcher
        # keeps scratch buffers).
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
        unnormalised: tuple[U8, U8] | None = None,
    ) -> UnfilteredDisparity:
        """Fixed-point disparities of gray images (H, W) uint8 as
        :meth:`rig.stereo.StereoMatcher.compute` gives them (with ``lr_check`` the mirrored
        pair's too), and both images' contrast normalisation. ``pool``: threads for the
        normalisation and the fine levels' bands; ``temporal_prior``: the live service's
        (frames in order, one stream); ``unnormalised``: with ``confirm``, the pair before the
        matcher input's normalisation (its size)."""
        lv = self.level
        normalised = Normalisation(left, right, pool)
        # Halved until the coarse level: a coarse scale of 4 has a band search at 1/2 too.
        pyramid = [(left, right)]
        while len(pyramid) < lv.scale.bit_length():
            pyramid.append((downsample(pyramid[-1][0], 2), downsample(pyramid[-1][1], 2)))
        coarse_left, coarse_right = pyramid.pop()
        coarse_seen = None if seen is None else seen.at_scale(lv.scale)
        if lv.confirm:  # (no temporal prior: its history is of one search)
            found = self.coarse_search(coarse_left, coarse_right, coarse_seen, pool)
            if unnormalised is not None:
                other = [_halved(image, lv.scale) for image in unnormalised]
                found = _agreed(found, self.coarse_search(other[0], other[1], coarse_seen, pool))
        elif temporal_prior:
            found = self._with_prior(coarse_left, coarse_right, coarse_seen, pool)
        else:  # (a pair outside the stream leaves the stream's history alone)
            found = self.coarse_search(coarse_left, coarse_right, coarse_seen, pool)
        fields = [found.left] if found.mirrored is None else [found.left, found.mirrored]
        # The coarse level's unmatched columns, full resolution, per view (the right one's are on
        # its right, so on the left of the mirrored view): the fine levels leave them unmatched too.
        unsearched = min(left.shape[1], lv.scale * found.right_unsearched_from)
        blind = [lv.blind, left.shape[1] - unsearched]
        while len(pyramid) > 1:  # the intermediate levels, in their own pixels
            step = 1 << (len(pyramid) - 1)
            images = pyramid.pop()
            pair = (
                quantise_normalised(normalise_contrast(images[0])),
                quantise_normalised(normalise_contrast(images[1])),
            )
            fixed = self._fine(pair, fields, pool, step, blind)
            fields = [_pixels(f, (lv.d_min // step) * 16) for f in fixed]
        norm_left, norm_right = normalised.result()
        fixed = self._fine(
            (quantise_normalised(norm_left), quantise_normalised(norm_right)), fields, pool, 1, blind
        )
        return UnfilteredDisparity(
            fixed[0], fixed[1] if len(fixed) > 1 else None, unsearched, (norm_left, norm_right)
        )

    def coarse_search(
        self, left: U8, right: U8, seen: SeenColumns | None, pool: Executor | None
    ) -> CoarseSearch:
        """The coarse level's matcher on coarse images (the mirrored pair's on ``pool`` while
        the left view's runs here), speckles removed, in coarse px; where it finds a disparity
        beyond the range (a surface too near), none.

        The images get repeated columns either side first: on the left as many as the search
        goes beyond the range, so that its unmatched band stays the range's (those disparities
        only say "too near"), on the right as many again (the mirrored pair's band) and a few:
        OpenCV's SGBM gives its last two columns disparity 0, harmless at full resolution (no
        range) but a hypothesis of 0 to 1 px for four full-resolution columns (a far surface)."""
        lv = self.level
        w = left.shape[1]
        beyond, pad = lv.beyond, lv.window // 2 + 1
        left, right = (
            np.asarray(
                cv2.copyMakeBorder(img, 0, 0, beyond, beyond + pad, cv2.BORDER_REPLICATE), dtype=np.uint8
            )
            for img in (left, right)
        )
        if seen is not None:
            seen = SeenColumns(*((a + beyond, b + beyond) for a, b in (seen.left, seen.right)))
        valid_from = lv.coarse_min * 16
        # Beyond the range (a full-resolution pixel's tolerance): too near, no hypothesis.
        too_near = (lv.d_max + 1) * 16 // lv.scale
        first, second = self.coarse

        def mirrored_view() -> tuple[F32, int]:
            fixed, unsearched = second.mirrored_view(left, right, seen)
            second.remove_speckles(fixed)  # mirrored: the right-hand padding is on its left
            return _pixels(fixed[:, beyond + pad : beyond + pad + w], valid_from, too_near), unsearched

        other = submit_or_run(pool, mirrored_view) if lv.lr_check else None
        try:
            fixed = first.left_view(left, right, seen)
            first.remove_speckles(fixed)
            found = _pixels(fixed[:, beyond : beyond + w], valid_from, too_near)
        finally:
            done = other.result() if other is not None else None
        if done is None:
            return CoarseSearch(found, None, w)
        return CoarseSearch(found, done[0], min(w, done[1] - beyond))

    def _with_prior(
        self, left: U8, right: U8, seen: SeenColumns | None, pool: Executor | None
    ) -> CoarseSearch:
        """The coarse search of the rows the temporal prior says changed, over its history."""
        h = left.shape[0]
        spans = self.prior.spans(left, right)
        fresh = []
        for a, b in spans:
            if (a, b) == (0, h):
                fresh.append(self.coarse_search(left, right, seen, pool))
                continue
            # Rows of context above and below: the matcher's paths run through them.
            top, bottom = max(0, a - PRIOR_MARGIN_ROWS), min(h, b + PRIOR_MARGIN_ROWS)
            part = self.coarse_search(left[top:bottom], right[top:bottom], seen, pool)
            keep = slice(a - top, b - top)
            mirrored = None if part.mirrored is None else part.mirrored[keep]
            fresh.append(CoarseSearch(part.left[keep], mirrored, part.right_unsearched_from))
        return self.prior.merge(left, right, spans, fresh)

    def _fine(
        self, images: tuple[U8, U8], fields: list[F32], pool: Executor | None, step: int, blind: list[int]
    ) -> list[I16]:
        """The band search at 1/``step`` of full resolution, of the left view and, given a
        second field, of the mirrored pair, around the hypotheses of the next coarser level's
        ``fields`` (its px; NaN invalid); in row bands on ``pool``. Each view's first
        ``blind`` columns (full resolution px) are left unmatched (the coarse level's hypotheses
        reach a pixel into them)."""
        lv = self.level
        ref, other = images
        shape = (ref.shape[0], ref.shape[1])
        inward = CONFIRM_INWARD if lv.confirm else None
        views = [(ref, other, band_hypotheses(fields[0], shape[1], shape[0], 2, inward))]
        if len(fields) > 1:
            mirrored = (
                np.asarray(cv2.flip(other, 1), dtype=np.uint8),
                np.asarray(cv2.flip(ref, 1), dtype=np.uint8),
            )
            views.append((*mirrored, band_hypotheses(fields[1], shape[1], shape[0], 2, inward)))
        outputs = [np.empty(shape, dtype=np.int16) for _ in views]
        d_range = (lv.d_min // step, -(-lv.d_max // step))
        invalid = (d_range[0] - 1) * 16

        def band(view: int, r0: int, r1: int) -> None:
            ref, other, hyps = views[view]
            found = search_rows(
                ref,
                other,
                hyps,
                (r0, r1),
                window=lv.window,
                d_range=d_range,
                invalid=invalid if step > 1 else lv.invalid,
                parabola=lv.parabola and step == 1,
            )
            start = -(-blind[view] // step)
            outputs[view][r0:r1, start:] = found[:, start:]

        for view, out in enumerate(outputs):
            out[:, : -(-blind[view] // step)] = invalid if step > 1 else lv.invalid
        futures: list[Future[None]] = []
        for view in range(len(views)):
            for r0 in range(0, shape[0], BAND_ROWS):
                futures.append(submit_or_run(pool, band, view, r0, min(shape[0], r0 + BAND_ROWS)))
        for future in futures:
            future.result()
        return outputs


#: Coarse disparities two searches may differ by and still agree (coarse px).
CONFIRM_TOLERANCE = 1.0
#: Coarse pixels the hypotheses of a confirmed coarse result keep away from its invalid pixels.
CONFIRM_INWARD = 2


def _agreed(first: CoarseSearch, second: CoarseSearch) -> CoarseSearch:
    """The disparities of ``first`` where ``second`` agrees within :data:`CONFIRM_TOLERANCE`
    (NaN elsewhere), per view."""

    def both(a: F32, b: F32) -> F32:
        out = a.copy()
        with np.errstate(invalid="ignore"):
            out[~(np.abs(a - b) <= CONFIRM_TOLERANCE)] = np.nan
        return out

    mirrored = None
    if first.mirrored is not None and second.mirrored is not None:
        mirrored = both(first.mirrored, second.mirrored)
    unsearched = min(first.right_unsearched_from, second.right_unsearched_from)
    return CoarseSearch(both(first.left, second.left), mirrored, unsearched)


def _pixels(fixed: I16, valid_from: int, beyond: int | None = None) -> F32:
    """A fixed-point disparity (1/16 px) in px, NaN below ``valid_from`` and above ``beyond``
    (1/16 px)."""
    out = fixed.astype(np.float32)
    out *= np.float32(1.0 / 16.0)
    out[fixed < valid_from] = np.nan
    if beyond is not None:
        out[fixed > beyond] = np.nan
    return out
