"""The depth pipeline's post-processing stage (:meth:`rig.pipeline.DepthPipeline.postprocess`): the matcher's
speckle removal, then subpixel refinement, filters, confidence and depth of one matched pair.

Its sections: the refinement's preparation (image normalisation on the pool while this thread
removes the matcher's speckles, then the refinement's inputs); per row band, the subpixel
refinement, the median filter, confidence and (without the temporal filter) depth and range; then
the temporal filter and depth and range of the whole frame; the stage's timings.

Everything but the temporal filter is row-local, so it runs in horizontal bands across the cores
(:func:`rig.bands.run_in_bands`, margins so every row sees what one pass would see): this stage
is on every frame's critical path. A stage's time is its longest band's. Only the columns around
the valid pixels are worked on (:func:`active_columns`).
"""

from __future__ import annotations

import functools
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.models import LatLonModel, PinholeModel
from rig import priority
from rig.bands import run_in_bands
from rig.depth import disparity_to_depth, latlon_range, pixel_ray_norms
from rig.filters import TemporalFilter, fill_where, median_filter
from rig.stereo import MatchedDisparity, StereoMatcher, StereoParams
from rig.subpixel import (
    Normalisation,
    RefinementInputs,
    confidence_from_sigma,
    refine_rows,
    refinement_inputs,
)

__all__ = [
    "SUBPIXEL_REACH_PX",
    "PostprocessOutputs",
    "PostprocessStage",
    "active_columns",
    "refine_pool",
    "trusted_disparity_floor",
]

F32 = NDArray[np.float32]
U8 = NDArray[np.uint8]
Mask = NDArray[np.bool_]
StageTimes = dict[str, float]

_refine_pool: ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()
_refine_pool_nice: int | None = None
_REFINE_THREADS = min(4, os.cpu_count() or 1)
#: How far below its integer cost minimum the matcher's interpolation can place a disparity.
SUBPIXEL_REACH_PX = 0.5


def trusted_disparity_floor(params: StereoParams) -> float:
    """The smallest disparity (px) that is a measurement: half a pixel above the lowest one the
    matcher searches (and above zero). Lower ones come only from a cost minimum on the search
    range's edge, which says nothing of where the true minimum lies, or from the refinement's
    step past it; their range would be invented (B/d: kilometres from a hundredth of a pixel),
    so they are invalid. That bounds the range: on the lat-lon pair's axis ``fx·B/floor``."""
    return max(params.min_disparity, 0) + SUBPIXEL_REACH_PX


def refine_pool() -> ThreadPoolExecutor | None:
    """The process's threads for the banded post-processing stage (:func:`rig.bands.run_in_bands`);
    None on a single core. Shared by all pipelines: the post-processing stage is serialised anyway. Its
    threads take the depth threads' priority (:mod:`rig.priority`) when they start; a new
    priority gets a new pool (the old one's threads finish their bands and end)."""
    global _refine_pool, _refine_pool_nice
    if _REFINE_THREADS < 2:
        return None
    nice = priority.configured_nice()
    with _pool_lock:
        if _refine_pool is None or nice != _refine_pool_nice:
            if _refine_pool is not None:
                _refine_pool.shutdown(wait=False)
            _refine_pool = ThreadPoolExecutor(
                _REFINE_THREADS, thread_name_prefix="rig-refine", initializer=priority.apply_to_current_thread
            )
            _refine_pool_nice = nice
        return _refine_pool


@dataclass
class PostprocessOutputs:
    """The post-processing stage's output arrays (H, W), filled band by band."""

    disparity: F32
    valid: Mask
    confidence: F32 | None
    depth: F32
    range: F32

    @classmethod
    def empty(
        cls, shape: tuple[int, ...], *, with_confidence: bool, cols: slice, range_is_depth: bool
    ) -> PostprocessOutputs:
        """Arrays to fill in columns ``cols`` (step 1; depth and range everywhere), invalid
        outside them. ``range_is_depth``: one array for both (the lat-lon pair)."""

        def f32() -> F32:
            return np.empty(shape, dtype=np.float32)

        depth = f32()
        out = cls(
            f32(),
            np.empty(shape, dtype=bool),
            f32() if with_confidence else None,
            depth,
            depth if range_is_depth else f32(),
        )
        for outside in (slice(0, cols.start), slice(cols.stop, None)):
            out.disparity[:, outside] = np.nan
            out.valid[:, outside] = False
            if out.confidence is not None:
                out.confidence[:, outside] = 0.0
        return out


def active_columns(valid: Mask, margin: int) -> slice:
    """The columns holding every valid pixel, and ``margin`` more either side. Outside them
    everything is invalid, so the post-processing stage need not look: the matcher leaves its first
    ``min_disparity + disparity_range`` columns invalid (a fifth of a 640 px wide frame by
    default). Within, every valid pixel sees what it would see in the whole frame (as across a
    band's margin; and invalid pixels add nothing to the refinement's sums)."""
    w = valid.shape[1]
    cols = np.flatnonzero(valid.any(axis=0))
    if cols.size == 0:
        return slice(0, w)
    return slice(max(0, int(cols[0]) - margin), min(w, int(cols[-1]) + 1 + margin))


@dataclass
class _Prepared:
    """One pair after the refinement's preparation: the matcher's disparity (speckles
    removed), the columns to work on with the bands' margin, the refinement's inputs (None
    without refinement) and the two parts' times in ms."""

    disparity: F32
    valid: Mask
    cols: slice
    margin: int
    inputs: RefinementInputs | None
    speckle_ms: float  # the matcher's speckle removal: the match stage's time
    prep_ms: float  # starting the normalisation, making the inputs: the refine stage's time


def _prepare(
    p: StereoParams,
    left_gray: U8,
    right_gray: U8,
    disparity_of: Callable[[], MatchedDisparity],
    pool: Executor | None,
    made: tuple[F32, F32] | None = None,
) -> _Prepared:
    """The refinement's preparation around the matcher's speckle removal (``disparity_of``);
    ``made``: the images' normalisation if the matcher made it."""
    refine = p.subpixel or p.confidence
    t0 = time.perf_counter()
    # The refinement's image normalisation needs no disparity: it runs on the pool while this
    # thread removes the matcher's speckles (single-threaded).
    normalised = None
    if refine:
        normalised = Normalisation.ready(*made) if made else Normalisation(left_gray, right_gray, pool)
    t_norm = time.perf_counter()
    raw = disparity_of()
    t_raw = time.perf_counter()
    margin = (p.subpixel_window // 2 if refine else 0) + p.median // 2
    cols = active_columns(raw.valid, margin)
    _drop_search_edge(raw, p.min_disparity, cols)
    inputs = None
    if refine:
        inputs = refinement_inputs(left_gray, right_gray, raw.disparity, cols=cols, normalised=normalised)
    # The refinement's preparation: starting the normalisation, and the inputs after the speckle
    # pass (which counts as the match stage's).
    prep_ms = ((t_norm - t0) + (time.perf_counter() - t_raw)) * 1e3
    return _Prepared(raw.disparity, raw.valid, cols, margin, inputs, (t_raw - t_norm) * 1e3, prep_ms)


def _drop_search_edge(raw: MatchedDisparity, min_disparity: int, cols: slice) -> None:
    """Invalidate (in place, within ``cols``) the pixels whose cost minimum lies on the lowest
    disparity searched: the matcher reports them as exactly ``min_disparity``, uninterpolated,
    and the true minimum may be anywhere below (a far point, or none at all). Before the
    refinement and the median, so that they neither refine nor vote."""
    disparity, valid = raw.disparity[:, cols], raw.valid[:, cols]
    edge = disparity <= np.float32(min_disparity)  # False where NaN (invalid)
    if edge.any():
        valid[edge] = False
        disparity[edge] = np.nan


class _Bands:
    """The row-local sections of one pair's post-processing stage, called per row band by
    :func:`rig.bands.run_in_bands`: subpixel refinement, median filter, confidence and, given
    ``depth_rows``, depth; written into ``out``, each band's times kept."""

    def __init__(
        self,
        p: StereoParams,
        prep: _Prepared,
        out: PostprocessOutputs,
        depth_rows: Callable[[PostprocessOutputs, int, int], StageTimes] | None,
    ) -> None:
        self.p = p
        self.prep = prep
        self.out = out
        self.depth_rows = depth_rows
        self.band_ms: list[StageTimes] = []

    def __call__(self, a: int, b: int, r0: int, r1: int) -> None:
        p, out, cols = self.p, self.out, self.prep.cols
        rows, keep, dst = slice(a, b), slice(r0 - a, r1 - a), (slice(r0, r1), cols)
        b0 = time.perf_counter()
        d, v, sigma = self._refine(rows)
        b1 = time.perf_counter()
        if p.median:
            d, v = median_filter(d, v, p.median)
        out.disparity[dst] = d[keep]
        out.valid[dst] = v[keep]
        if out.confidence is not None and sigma is not None:
            out.confidence[dst] = self._confidence(sigma[keep], d[keep])
        b2 = time.perf_counter()
        times = {"refine": (b1 - b0) * 1e3, "filters": (b2 - b1) * 1e3}
        if self.depth_rows is not None:
            times.update(self.depth_rows(out, r0, r1))
        self.band_ms.append(times)

    def _refine(self, rows: slice) -> tuple[F32, Mask, F32 | None]:
        """The subpixel refinement of input rows ``rows`` (of the active columns): disparity,
        validity and σ (None when not asked for or without refinement)."""
        p, prep = self.p, self.prep
        d, v = prep.disparity[rows, prep.cols], prep.valid[rows, prep.cols]
        if prep.inputs is None:
            return d, v, None
        ref = refine_rows(
            prep.inputs.rows(rows), d, v, p.subpixel_window, apply=p.subpixel, want_sigma=p.confidence
        )
        return ref.disparity, v, ref.sigma

    def _confidence(self, sigma: F32, disparity: F32) -> F32:
        """Confidence of output rows from their σ and their filtered disparity."""
        # Here, not after the temporal filter: it keeps the valid mask. σ is inf (confidence 0)
        # where the refinement's input was invalid; the median invalidates a few more: NaN there
        # (0·NaN disparity), then 0. (Contiguous, then copied: numpy is 2-3× slower on a column
        # window.)
        confidence = confidence_from_sigma(sigma, self.p.confidence_sigma)
        if self.p.median:
            cv2.scaleAdd(disparity, 0.0, confidence, dst=confidence)
            cv2.patchNaNs(confidence, 0.0)
        return confidence

    def stage_ms(self) -> StageTimes:
        """Each section's time: its longest band's."""
        return {k: max(t.get(k, 0.0) for t in self.band_ms) for k in ("refine", "filters", "depth")}


class PostprocessStage:
    """A pipeline's post-processing stage for the rectified pair of left view ``camera`` (pinhole or
    lat-lon) and baseline ``baseline_m``: call it in frame order (the temporal filter's history);
    callers are serialised. ``matcher`` is the pipeline's first matcher, whose parameters start
    the temporal filter."""

    def __init__(self, camera: PinholeModel | LatLonModel, baseline_m: float, matcher: StereoMatcher) -> None:
        self.camera = camera
        self.baseline_m = baseline_m
        # Range per metre of depth of every pixel (the pinhole pair; the lat-lon pair's depth is
        # its range).
        self._ray_norms = (
            pixel_ray_norms(camera) if isinstance(camera, PinholeModel) else np.ones((0, 0), np.float32)
        )
        params = matcher.params
        self._temporal = TemporalFilter(params.temporal_alpha, params.temporal_reset)
        self._temporal_owner = matcher

    def __call__(
        self,
        matcher: StereoMatcher,
        left_gray: U8,
        right_gray: U8,
        disparity_of: Callable[[], MatchedDisparity],
        normalised: tuple[F32, F32] | None = None,
    ) -> tuple[PostprocessOutputs, float, StageTimes]:
        """The post-processing stage of the pair whose gray VPC images are ``left_gray``/``right_gray``,
        with the parameters of the ``matcher`` that matched it; ``disparity_of()`` removes its
        speckles and gives its disparity; ``normalised``: the images' contrast normalisation if
        the matcher made it. Returns the outputs, the speckle removal's time (ms) and the
        stage's times (ms) by section: refine, filters, depth."""
        p = matcher.params
        pool = refine_pool()
        prep = _prepare(p, left_gray, right_gray, disparity_of, pool, normalised)
        temporal = p.temporal_alpha > 0.0
        self._follow(matcher)
        out = PostprocessOutputs.empty(
            prep.disparity.shape,
            with_confidence=p.confidence,
            cols=prep.cols,
            range_is_depth=isinstance(self.camera, LatLonModel),
        )
        depth_rows = functools.partial(self._depth_rows, floor=trusted_disparity_floor(p))
        bands = _Bands(p, prep, out, None if temporal else depth_rows)
        run_in_bands(bands, prep.disparity.shape[0], _REFINE_THREADS, prep.margin, pool)
        stage = bands.stage_ms()
        stage["refine"] += prep.prep_ms
        if temporal:
            self._temporal_and_depth(out, stage, depth_rows)
        return out, prep.speckle_ms, stage

    @property
    def temporal_state(self) -> F32 | None:
        """The temporal filter's history after the last frame (None: empty)."""
        return self._temporal.state

    @temporal_state.setter
    def temporal_state(self, state: F32 | None) -> None:
        self._temporal.state = state

    def _follow(self, matcher: StereoMatcher) -> None:
        if matcher is not self._temporal_owner:
            # New parameters: history made under the old ones is not averaged in.
            p = matcher.params
            self._temporal = TemporalFilter(p.temporal_alpha, p.temporal_reset)
            self._temporal_owner = matcher

    def _temporal_and_depth(
        self,
        out: PostprocessOutputs,
        stage: StageTimes,
        depth_rows: Callable[[PostprocessOutputs, int, int], StageTimes],
    ) -> None:
        """The temporal filter over the whole frame, then its depth; their times added to
        ``stage``'s filters and depth."""
        t0 = time.perf_counter()
        out.disparity = self._temporal(out.disparity, out.valid)
        stage["filters"] += (time.perf_counter() - t0) * 1e3
        for key, ms in depth_rows(out, 0, out.disparity.shape[0]).items():
            stage[key] += ms

    def _depth_rows(self, out: PostprocessOutputs, r0: int, r1: int, *, floor: float) -> StageTimes:
        """Depth and range of rows ``[r0, r1)`` of ``out`` (in place; whole rows: numpy is 2-3×
        slower on a column window than on contiguous rows), invalid below the disparity
        ``floor`` (:func:`trusted_disparity_floor`); its time."""
        t0 = time.perf_counter()
        disparity, valid = out.disparity[r0:r1], out.valid[r0:r1]
        camera = self.camera
        if isinstance(camera, LatLonModel):
            depth = latlon_range(disparity, camera, self.baseline_m, out=out.range[r0:r1])
        else:
            depth = disparity_to_depth(disparity, camera.fx, self.baseline_m, out=out.depth[r0:r1])
            np.multiply(depth, self._ray_norms[r0:r1], out=out.range[r0:r1])
        # d below the floor (and a lat-lon triangle that does not close) has no depth: invalid
        # everywhere, so the arrays agree pixel for pixel.
        gone = ~np.isfinite(depth)
        gone |= disparity < np.float32(floor)
        gone &= valid
        if gone.any():
            valid ^= gone  # gone ⊂ valid: clears them
            fill_where(disparity, np.nan, gone)
            fill_where(depth, np.nan, gone)  # below the floor depth was finite
            if out.range is not out.depth:
                fill_where(out.range[r0:r1], np.nan, gone)
            if out.confidence is not None:
                fill_where(out.confidence[r0:r1], 0.0, gone)
        return {"depth": (time.perf_counter() - t0) * 1e3}
