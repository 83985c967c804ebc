"""The fine level of the coarse-to-fine search (:mod:`rig.coarse_to_fine`): block matching at full
resolution within narrow disparity bands around per-pixel hypotheses.

A hypothesis is a disparity field ``h`` (H, W) (NaN: none at that pixel) and a half-width ``k``;
the search tries ``round(h) + j`` for every ``j`` in ``[-k, k]`` at every pixel at once. The
cost of a try is the sum of absolute differences over a ``window``² block between the reference
image and the other image gathered at ``x − round(h(x)) − j``: every pixel of the block is
gathered at its own hypothesis, i.e. the other image is warped by the hypothesis field and
matched at one residual shift ``j`` (the field is smooth where the surface is; where it is not,
another hypothesis proposes the other side's disparity). The images are the refinement's local
contrast normalisation (:func:`rig.subpixel.normalise_contrast`) quantised to uint8, so the cost
ignores the two cameras' gain and offset, and a try is a few integer OpenCV passes: one
nearest-neighbour remap (the shift ``j`` is a column offset of the source image, so one map
serves a whole hypothesis), an absolute difference, a box sum and two masked copies where the
try beats the best so far.

The search works in row bands (:data:`BAND_ROWS` rows and margins, laid out the same whatever the
number of threads), whose working set stays in the cache through every try: over a whole
661×1064 frame the same passes took twice the CPU time. The margins make every band's output
the whole frame's, bit for bit.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = [
    "BAND_ROWS",
    "NONE",
    "BandSearch",
    "HypothesesOf",
    "Hypothesis",
    "of_rows",
    "quantise_normalised",
    "search_rows",
]

U8 = NDArray[np.uint8]
I16 = NDArray[np.int16]
U16 = NDArray[np.uint16]
F32 = NDArray[np.float32]

#: Grey levels per unit of normalised contrast in the quantised images (±4 units fit in uint8).
QUANT_SCALE = 32.0
#: Output rows per band of the search.
BAND_ROWS = 128
_NO_COST = int(np.iinfo(np.uint16).max)
# OpenCV calls with a scalar operand or without a second map, which its type stubs leave out.
_cv: Any = cv2
_NOT_KEPT = int(np.iinfo(np.int8).min)


def quantise_normalised(normalised: F32) -> U8:
    """A contrast-normalised image (H, W) float32 as uint8: ``round(n·32 + 128)``, saturated."""
    out = np.empty(normalised.shape, dtype=np.uint8)
    cv2.addWeighted(normalised, QUANT_SCALE, normalised, 0.0, 128.0, dst=out, dtype=cv2.CV_8U)
    return out


#: A hypothesis's value where it proposes nothing.
NONE = int(np.iinfo(np.int16).min)


@dataclass(frozen=True)
class Hypothesis:
    """A disparity field (H, W) int16 of whole pixels, :data:`NONE` where it proposes nothing,
    searched ±``half_width``."""

    centre: I16
    half_width: int


@functools.lru_cache(maxsize=8)
def _grid(h: int, w: int) -> tuple[I16, I16]:
    """Each pixel's x and y (H, W) int16: the two halves of an integer remap's identity map."""
    xs = np.ascontiguousarray(np.broadcast_to(np.arange(w, dtype=np.int16)[None, :], (h, w)))
    ys = np.ascontiguousarray(np.broadcast_to(np.arange(h, dtype=np.int16)[:, None], (h, w)))
    xs.flags.writeable = False
    ys.flags.writeable = False
    return xs, ys


class BandSearch:
    """The search of one block of rows: reference ``ref`` against ``other`` (both (h, W) uint8,
    from :func:`quantise_normalised`); a disparity ``d`` matches ``ref(x)`` with ``other(x − d)``
    and is kept within ``[d_min, d_max]``. Call :meth:`search` per hypothesis, then
    :meth:`fixed_point`."""

    def __init__(self, ref: U8, other: U8, window: int, d_min: int, d_max: int, reach: int) -> None:
        self.ref = ref
        self.window = window
        self.d_min = d_min
        self.d_max = d_max
        self._reach = reach  # the largest |j| or parabola step asked for
        # ``other`` with ``reach`` replicated columns either side: its view from column
        # ``reach − j`` is other(u − j), so one map serves every shift j.
        self._padded: U8 = np.asarray(cv2.copyMakeBorder(other, 0, 0, reach, reach, cv2.BORDER_REPLICATE))
        h, w = ref.shape
        self._grid = _grid(h, w)
        self.best_cost: U16 = np.full((h, w), _NO_COST, dtype=np.uint16)
        self.best: I16 = np.zeros((h, w), dtype=np.int16)
        # With :meth:`search`'s ``keep``: that hypothesis's costs per shift, and the shift of
        # each pixel's best try if it is that hypothesis's (else :data:`_NOT_KEPT`).
        self._kept: dict[int, U16] = {}
        self._kept_shift: NDArray[np.int8] | None = None

    def _shifted(self, j: int) -> U8:
        w = self.ref.shape[1]
        start = self._reach - j
        return self._padded[:, start : start + w]

    def _map(self, disparity: I16, where: U8 | None = None) -> I16:
        """The integer remap (h, W, 2) to ``(x − disparity, y)`` (only ``where`` it is non-zero;
        ``(x, y)`` elsewhere)."""
        xs, ys = self._grid
        columns = xs.copy()
        cv2.subtract(xs, disparity, dst=columns, mask=where)
        return np.asarray(cv2.merge([columns, ys]), dtype=np.int16)

    def _cost(self, columns: I16, j: int) -> U16:
        """Block cost of matching each pixel with ``other`` at ``columns − j``."""
        gathered = _cv.remap(
            self._shifted(j), columns, None, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE
        )
        cv2.absdiff(self.ref, gathered, dst=gathered)
        k = (self.window, self.window)
        return np.asarray(cv2.boxFilter(gathered, cv2.CV_16U, k, normalize=False), dtype=np.uint16)

    def search(self, hypothesis: Hypothesis, *, keep: bool = False) -> None:
        """Try every shift of ``hypothesis``'s band at every pixel it proposes for; keeps each
        pixel's best try so far (earlier tries win ties). ``keep``: remember this hypothesis's
        costs for the parabola (:meth:`fixed_point`)."""
        d0 = hypothesis.centre
        proposes = _cv.compare(d0, NONE, cv2.CMP_NE)
        # A pixel it proposes nothing for is gathered at disparity 0 (it still sits in its
        # neighbours' blocks).
        columns = self._map(d0, proposes)
        if keep:
            self._kept = {}
            self._kept_shift = np.full(d0.shape, _NOT_KEPT, dtype=np.int8)
        for j in range(-hypothesis.half_width, hypothesis.half_width + 1):
            cost = self._cost(columns, j)
            better = cv2.compare(cost, self.best_cost, cv2.CMP_LT)
            cv2.bitwise_and(better, proposes, dst=better)
            # d0 + j within [d_min, d_max]
            cv2.bitwise_and(better, cv2.inRange(d0, self.d_min - j, self.d_max - j), dst=better)
            cv2.copyTo(cost, better, self.best_cost)
            cv2.copyTo(np.asarray(_cv.add(d0, j), dtype=np.int16), better, self.best)
            if self._kept_shift is not None:
                if keep:
                    self._kept[j] = cost
                self._kept_shift[better != 0] = j if keep else _NOT_KEPT

    def fixed_point(self, invalid: int, parabola: bool) -> I16:
        """Each pixel's best disparity in 1/16 px (OpenCV's fixed point), ``invalid`` where no
        hypothesis proposed one. ``parabola``: with a subpixel offset from a parabola through the
        costs one pixel either side (as SGBM's own) where the kept hypothesis has them; else
        whole pixels (a subpixel refinement follows)."""
        found = self.best_cost != _NO_COST
        fixed = self.best * np.int16(16)
        if parabola and self._kept_shift is not None:
            # Through the kept hypothesis's costs (one warp for all three: consistent blocks),
            # where its best try has a neighbour on either side.
            offset = np.zeros(fixed.shape, dtype=np.float32)
            for j in self._kept:
                if j - 1 in self._kept and j + 1 in self._kept:
                    here = self._kept_shift == j
                    below, centre, above = (self._kept[k][here].astype(np.float32) for k in (j - 1, j, j + 1))
                    curvature = below + above - 2.0 * centre
                    with np.errstate(divide="ignore", invalid="ignore"):
                        step = np.where(curvature > 0.0, (below - above) / (2.0 * curvature), 0.0)
                    offset[here] = np.clip(step, -0.5, 0.5)
            fixed = np.rint((self.best + offset) * 16.0).astype(np.int16)
        fixed[~found] = invalid
        return fixed


HypothesesOf = Callable[[int, int], Sequence[Hypothesis]]
"""``hypotheses(a, b)``: the hypotheses of image rows ``[a, b)`` ((b − a, W) each)."""


def of_rows(hypotheses: Sequence[Hypothesis]) -> HypothesesOf:
    """The rows of whole-image hypotheses (H, W)."""
    return lambda a, b: [Hypothesis(h.centre[a:b], h.half_width) for h in hypotheses]


def search_rows(
    ref: U8,
    other: U8,
    hypotheses: HypothesesOf,
    rows: tuple[int, int],
    *,
    window: int,
    d_range: tuple[int, int],
    invalid: int,
    parabola: bool,
) -> I16:
    """:class:`BandSearch` of output rows ``rows = (r0, r1)`` of the whole images ``ref``/``other``
    (H, W), with the hypotheses of the rows it reads: the block of rows with the margin that
    makes it exact (a block cost reaches ``window // 2`` rows). ``parabola``: a subpixel offset
    where the first hypothesis's band (searched one shift wider) has the best try."""
    r0, r1 = rows
    margin = window // 2
    a, b = max(0, r0 - margin), min(ref.shape[0], r1 + margin)
    proposed = hypotheses(a, b)
    reach = max(h.half_width for h in proposed) + 1
    search = BandSearch(ref[a:b], other[a:b], window, d_range[0], d_range[1], reach)
    for i, h in enumerate(proposed):
        # With the parabola: the first hypothesis one shift wider, its costs kept.
        wider = parabola and i == 0
        search.search(Hypothesis(h.centre, h.half_width + wider), keep=wider)
    return search.fixed_point(invalid, parabola)[r0 - a : r1 - a]
