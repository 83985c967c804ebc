"""The depth pipeline of one stereo pair: fisheye pair → rectified pair (cached LUT remap) →
disparity → range and depth.

``DepthPipeline(rig, config, stereo)`` designs the rectified pair of two of ``rig``'s cameras
(:func:`rig.rectified.design_rectified_pair`), builds (or loads from the cache) one lookup table
per camera, and holds them with the stereo matcher as the pair in effect
(:class:`rig.in_effect.PairInEffect`); ``process(left, right)`` returns a :class:`DepthFrame`
with per-stage timings.

``process`` is three stages that a pipelined caller (:mod:`rig.staged`) may run on three
threads, frame N+1's stage 1 while frame N is in stage 2 or 3: :meth:`rectify` (LUT remap + gray;
thread-safe), :meth:`match` (the matcher's search; serialised) and
:meth:`postprocess` (speckle removal, refinement, filters, confidence, depth; serialised, in
frame order for the temporal filter).

Thread safety: ``process`` may be called from several threads (a lock serialises them).
:meth:`apply` may be called from any thread: it is the one way the pair in effect changes (new
stereo parameters; the tables of a corrected calibration), swapped in as one object. The next
pair to reach :meth:`match` uses the new matcher; a pair is rectified and post-processed with one
geometry, whichever it started with, so no frame mixes two or is dropped.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.models import LatLonModel
from calibration.rig import Rig
from rig.depth import range_points
from rig.errors import ConfigError, PipelineError
from rig.field import image_border, region_outline
from rig.filters import fill_where, visible_in_right
from rig.heap import tune_allocator
from rig.in_effect import PairGeometry, PairInEffect
from rig.lut import Lut, percent_valid
from rig.lut_cache import CachedLut, LutCache
from rig.match_input import matcher_views
from rig.postprocess import PostprocessStage, refine_pool
from rig.reach import reaching
from rig.rectified import RectifiedPair, RectifiedPairConfig, pinhole_intrinsics
from rig.stereo import MatchedDisparity, StereoMatcher, StereoParams, UnfilteredDisparity

__all__ = [
    "DepthFrame",
    "DepthPipeline",
    "MatchedImages",
    "PairGeometry",
    "PairInEffect",
    "RectifiedImages",
    "tune_allocator",
]

log = logging.getLogger(__name__)

F32 = NDArray[np.float32]
U8 = NDArray[np.uint8]


@dataclass
class DepthFrame:
    """One processed pair. Arrays are (H, W) at the rectified view's size.

    ``range`` float32 m along each left rectified pixel's ray, NaN invalid; ``depth`` float32 m:
    z in the left VPC frame for the pinhole pair, the range itself (the same array) for the
    lat-lon pair, whose rays reach past 90° off its z axis; ``disparity`` float32 px, NaN
    invalid; ``valid`` bool; ``confidence`` float32 in [0, 1] (0 where invalid) or None;
    ``left_rect``/``right_rect`` uint8, gray or BGR like the input; ``timings_ms`` per stage, in
    one convention for every driver (:meth:`DepthPipeline.process`, the staged executor of the
    service, ``rig process``, ``rig export mcap`` and the cluster): **processing time**, each
    stage's own work in ms. ``remap`` (and ``decode``, which the staged executor adds: it decodes
    the frames) is the **sum** of the two cameras' times, whether they ran one after the other
    or on two threads at once; ``match``, ``refine``, ``filters``, ``depth`` the stage's; ``total``
    the sum of the stages. It is not a latency: stages of consecutive pairs overlap and wait for
    each other, and the wall time from capture to result is the frame's age (``X-Age-Ms``).
    ``searched``: the share of the pair the matcher searched afresh (the live stream's temporal
    prior kept its last search for the rest: :mod:`rig.temporal_prior`; 1.0 without it).
    """

    seq: int
    ts_ns: int
    depth: F32
    range: F32
    disparity: F32
    valid: NDArray[np.bool_]
    confidence: F32 | None
    left_rect: U8
    right_rect: U8
    timings_ms: dict[str, float] = field(default_factory=dict)
    searched: float = 1.0


@dataclass
class RectifiedImages:
    """Output of :meth:`DepthPipeline.rectify`: the VPC images (H, W[, 3]) uint8, their gray
    versions (H, W) uint8 (the same arrays for gray input), the two cameras' remap times summed
    (:class:`DepthFrame`'s convention) and the geometry that made them (None: the pipeline's
    current one)."""

    left_rect: U8
    right_rect: U8
    left_gray: U8
    right_gray: U8
    remap_ms: float
    geometry: PairGeometry | None = None


@dataclass
class MatchedImages:
    """Output of :meth:`DepthPipeline.match`: the matcher's output before its speckle removal
    and the matcher that made it (its parameters drive :meth:`DepthPipeline.postprocess`, which
    removes the speckles in place: a second ``postprocess`` of the same pair finds none left)."""

    rectified: RectifiedImages
    matcher: StereoMatcher
    unfiltered: UnfilteredDisparity
    match_ms: float
    searched: float = 1.0


def _reaching(params: StereoParams, rig: Rig, config: RectifiedPairConfig) -> StereoParams:
    """``params`` widened to reach ``min_range_m`` (rig.reach) on the pair ``config`` designs:
    its resolution and baseline are known before its field (which the search's blind band
    widens)."""
    if params.min_range_m is None:
        return params
    if config.projection == "latlon":
        fx, width = math.degrees(config.resolution_px_per_deg), None
    else:
        fx, width = pinhole_intrinsics(config).fx, config.pinhole_size[0]
    return reaching(params, config.projection, fx, rig.baseline(config.left, config.right), width)


def _width(in_effect: PairInEffect) -> int | None:
    """The width a pinhole pair's search must fit in (a lat-lon field widens with it)."""
    return in_effect.camera.width if in_effect.pair.projection == "pinhole" else None


def _check_params(params: StereoParams, width: int) -> None:
    if max(params.blind_band_px, params.disparity_range + max(params.min_disparity, 0)) >= width:
        raise ConfigError(
            f"stereo: disparity_range {params.disparity_range} + min_disparity {params.min_disparity} "
            f"(the coarse-to-fine search: {params.blind_band_px}) must be below the rectified view's "
            f"width {width}"
        )


def _gray(img: U8) -> U8:
    if img.ndim == 2:
        return img
    return np.asarray(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), dtype=np.uint8)


class DepthPipeline:
    """Depth from a fisheye pair of ``rig`` (see module doc): the pair ``config`` of ``rig``'s
    cameras (default: ``left`` and ``right``, the lat-lon pair), matched with ``stereo``.
    ``tune_malloc`` calls :func:`tune_allocator` (process-wide; the pipeline is what the
    process is for); ``luts``: the tables handed in instead of the cache's (a cluster's
    workers); ``log_field_warnings``: log :attr:`PairInEffect.field_warnings` at WARNING (False:
    the caller says them itself, and they are logged at DEBUG)."""

    def __init__(
        self,
        rig: Rig,
        config: RectifiedPairConfig | None = None,
        stereo: StereoParams | None = None,
        cache_dir: str | Path | None = None,
        *,
        tune_malloc: bool = True,
        luts: Mapping[str, CachedLut] | None = None,
        log_field_warnings: bool = True,
    ) -> None:
        self._field_log_level = logging.WARNING if log_field_warnings else logging.DEBUG
        if tune_malloc:
            tune_allocator()
        config = config or RectifiedPairConfig()
        params = _reaching(stereo or StereoParams(), rig, config)
        self.cache = LutCache(cache_dir)
        # A lat-lon field's default leaves room for the matcher's unmatched columns.
        reserve = params.blind_band_px
        geometry = PairGeometry.build(rig, config, self.cache, reserve, luts=luts)
        _check_params(params, geometry.pair.camera.width)
        self._in_effect = PairInEffect(config, geometry, StereoMatcher(params), reserve)
        self.names = self._in_effect.names
        self._report_field(self._in_effect)
        self._apply_lock = threading.Lock()
        self._process_lock = threading.Lock()
        self._match_lock = threading.Lock()
        # The geometry of the live stream's last frame (the temporal prior's history is of it).
        self._stream_geometry: PairGeometry | None = None
        self._postprocess_lock = threading.Lock()
        self._postprocess = PostprocessStage(self.pair.camera, self.baseline_m, self._in_effect.matcher)

    # ----- the pair in effect ------------------------------------------------------------------
    @property
    def in_effect(self) -> PairInEffect:
        """The rectified pair and stereo settings in effect (take it once per use: :meth:`apply`
        replaces it)."""
        return self._in_effect

    @property
    def geometry(self) -> PairGeometry:
        return self._in_effect.geometry

    @property
    def pair_config(self) -> RectifiedPairConfig:
        return self._in_effect.config

    @property
    def rig(self) -> Rig:
        return self._in_effect.geometry.rig

    @property
    def pair(self) -> RectifiedPair:
        return self._in_effect.pair

    @property
    def baseline_m(self) -> float:
        return self._in_effect.pair.baseline_m

    @property
    def lut_info(self) -> dict[str, CachedLut]:
        return self._in_effect.geometry.lut_info

    @property
    def luts(self) -> dict[str, Lut]:
        return self._in_effect.geometry.luts

    @property
    def stereo(self) -> StereoParams:
        return self._in_effect.stereo

    @property
    def valid_fraction(self) -> dict[str, float]:
        return {n: lut.valid_fraction for n, lut in self.luts.items()}

    def _report_field(self, in_effect: PairInEffect) -> None:
        """Log :attr:`PairInEffect.field_warnings` (at WARNING; at DEBUG for a caller that says
        them itself: ``log_field_warnings=False``, the command line) and the lat-lon pair's shape
        (INFO)."""
        for line in in_effect.field_warnings:
            log.log(self._field_log_level, "%s", line)
        pair, c = in_effect.pair, in_effect.pair.camera
        if isinstance(c, LatLonModel):
            log.info(
                "lat-lon pair %dx%d, %.3f px/deg, %d unmatched columns on the left; the lenses see "
                "%s / %s of its pixels",
                c.width,
                c.height,
                np.radians(c.fx),
                in_effect.field_reserve_px,
                *(
                    percent_valid(in_effect.geometry.lut_info[n].lut.valid_fraction)
                    for n in (pair.left, pair.right)
                ),
            )

    def apply(self, *, stereo: StereoParams | None = None, rig: Rig | None = None) -> PairInEffect:
        """The one way the pair in effect changes: new stereo parameters (the next pair to reach
        :meth:`match` uses them) and/or a corrected calibration of the same lenses and baseline
        length (the online rectification refinement: its tables are built, or read from the
        cache, on the calling thread, then swapped in at once; pairs already rectified are
        post-processed with the geometry they began with). Readers are never blocked; concurrent changes are
        applied one after the other. ConfigError for parameters the rectified view cannot take, or
        a calibration of other lenses or another baseline length (depth would change scale)."""
        with self._apply_lock:
            old = self._in_effect
            geometry = None if rig is None else self._corrected_geometry(old, rig)
            matcher = None
            if stereo is not None:
                stereo = reaching(
                    stereo, old.pair.projection, old.camera.fx, old.pair.baseline_m, _width(old)
                )
                _check_params(stereo, old.camera.width)
                matcher = StereoMatcher(stereo)
                self._warn_blind_band(old, stereo)
            new = old.changed(geometry=geometry, matcher=matcher)
            if geometry is not None:
                self._report_field(new)
            self._in_effect = new  # one reference swap: readers see the old or the new whole
            return new

    def _corrected_geometry(self, old: PairInEffect, rig: Rig) -> PairGeometry:
        for name in self.names:
            if (
                name not in rig.cameras
                or rig.cameras[name].to_dict() != old.geometry.rig.cameras[name].to_dict()
            ):
                raise ConfigError(
                    f"apply: camera {name!r} is not the same lens; restart with the new calibration"
                )
        # The rectified image grid stays: frames in flight and the post-processing share it.
        geometry = PairGeometry.build(rig, old.config, self.cache, old.field_reserve_px, old.camera)
        if abs(geometry.pair.baseline_m - old.pair.baseline_m) > 1e-9 * old.pair.baseline_m:
            raise ConfigError(
                f"apply: the baseline changes from {old.pair.baseline_m:.6f} m to "
                f"{geometry.pair.baseline_m:.6f} m; restart with the new calibration"
            )
        return geometry

    @staticmethod
    def _warn_blind_band(old: PairInEffect, params: StereoParams) -> None:
        if isinstance(old.camera, LatLonModel) and params.blind_band_px > old.field_reserve_px:
            log.warning(
                "stereo: the lat-lon field leaves room for %d unmatched columns, the new settings "
                "leave %d: the overlap's leftmost %d columns get no range until the service restarts",
                old.field_reserve_px,
                params.blind_band_px,
                params.blind_band_px - old.field_reserve_px,
            )

    def temporal_state(self) -> F32 | None:
        """The temporal filter's history after the last finished frame (None: empty), to carry
        into another pipeline of the same settings (the next chunk of a recording)."""
        with self._postprocess_lock:
            return self._postprocess.temporal_state

    def restore_temporal_state(self, state: F32 | None) -> None:
        """Continue from ``state`` (:meth:`temporal_state` of another pipeline; None: start a
        new history, as at the start of a recording)."""
        with self._postprocess_lock:
            self._postprocess.temporal_state = state

    # ----- stages ------------------------------------------------------------------------------
    def _check_input(self, name: str, img: NDArray[np.generic]) -> None:
        model = self.rig.cameras[name]
        if not isinstance(img, np.ndarray) or img.dtype != np.uint8:
            raise PipelineError(
                f"{name} image must be a uint8 numpy array, got {getattr(img, 'dtype', img)!r}"
            )
        if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
            raise PipelineError(f"{name} image must be gray (H, W) or BGR (H, W, 3), got shape {img.shape}")
        if img.shape[:2] != (model.height, model.width):
            raise PipelineError(
                f"{name} image is {img.shape[1]}x{img.shape[0]} but its calibration is "
                f"{model.width}x{model.height}"
            )

    def rectify_camera(self, name: str, image: U8, geometry: PairGeometry | None = None) -> tuple[U8, U8]:
        """One camera's VPC image (gray or BGR like ``image``) and its gray version, which is
        the same array for gray input, through ``geometry``'s table (default: the current one).
        Thread-safe: reads only the camera's LUT."""
        self._check_input(name, image)
        rect = (geometry or self._in_effect.geometry).lut_info[name].lut.remap(image)
        return rect, _gray(rect)

    def remap(self, left: U8, right: U8) -> tuple[U8, U8]:
        """The VPC pair from a fisheye pair (fixed-point bilinear remap, black outside the lens)."""
        geometry = self._in_effect.geometry
        pair = geometry.pair
        self._check_input(pair.left, left)
        self._check_input(pair.right, right)
        return geometry.lut_info[pair.left].lut.remap(left), geometry.lut_info[pair.right].lut.remap(right)

    def rectify(self, left: U8, right: U8) -> RectifiedImages:
        """Stage 1 of :meth:`process`: the VPC pair and its gray images (thread-safe)."""
        t0 = time.perf_counter()
        geometry = self._in_effect.geometry
        left_rect, left_gray = self.rectify_camera(geometry.pair.left, left, geometry)
        right_rect, right_gray = self.rectify_camera(geometry.pair.right, right, geometry)
        ms = (time.perf_counter() - t0) * 1e3
        return RectifiedImages(left_rect, right_rect, left_gray, right_gray, ms, geometry)

    def match(self, rect: RectifiedImages, *, temporal_prior: bool = False) -> MatchedImages:
        """Stage 2 of :meth:`process`: the current matcher's search (the speckle removal after it
        is :meth:`postprocess`'s, so that it overlaps the next pair's search). Callers are
        serialised (an OpenCV matcher keeps scratch buffers). ``temporal_prior``: the pairs are
        a live stream in order, and the search may reuse what it found where the images did not
        change (``stereo.temporal_prior``; the service's worker; :mod:`rig.temporal_prior`)."""
        with self._match_lock:
            matcher = self._in_effect.matcher
            geometry = rect.geometry or self._in_effect.geometry
            if temporal_prior and geometry is not self._stream_geometry:
                # A corrected calibration: what was found through the old tables does not carry over.
                matcher.forget()
                self._stream_geometry = geometry
            seen = geometry.seen
            t0 = time.perf_counter()
            views = matcher_views(matcher.params, rect.left_gray, rect.right_gray)
            unfiltered = matcher.compute(
                views.left,
                views.right,
                seen,
                pool=refine_pool(),
                temporal_prior=temporal_prior,
                unnormalised=views.unnormalised,
            )
            if views.changed:
                # The coarse-to-fine search's normalisation is of its input; the refinement's
                # is of the rectified images as they are (it makes its own).
                unfiltered.normalised = None
            searched = matcher.searched_fraction if temporal_prior else 1.0
            return MatchedImages(rect, matcher, unfiltered, (time.perf_counter() - t0) * 1e3, searched)

    def _disparity(self, matched: MatchedImages) -> MatchedDisparity:
        """The matcher's disparity of ``matched`` (speckles removed), LUT masks applied."""
        raw = matched.matcher.disparity_of(matched.unfiltered)
        disparity, valid = raw.disparity, raw.valid
        geometry = matched.rectified.geometry or self._in_effect.geometry
        left_mask, right_mask = geometry.left_mask, geometry.right_mask
        if left_mask is not None:
            valid &= left_mask
        if right_mask is not None:
            valid = visible_in_right(disparity, valid, right_mask)
        if left_mask is not None or right_mask is not None:
            fill_where(disparity, np.nan, ~valid)
        return MatchedDisparity(disparity, valid)

    def postprocess(self, matched: MatchedImages, seq: int = 0, ts_ns: int = 0) -> DepthFrame:
        """Stage 3 of :meth:`process`: the matcher's speckle removal, then refinement, filters,
        confidence and depth with the parameters of the matcher that made ``matched``
        (:class:`rig.postprocess.PostprocessStage`, in row bands across the cores). Call in frame order
        (the temporal filter's history); callers are serialised."""
        rect = matched.rectified
        with self._postprocess_lock:
            out, speckle_ms, stage = self._postprocess(
                matched.matcher,
                rect.left_gray,
                rect.right_gray,
                lambda: self._disparity(matched),
                matched.unfiltered.normalised,
            )
        timings = {"remap": rect.remap_ms, "match": matched.match_ms + speckle_ms, **stage}
        # Processing time, not wall time: pipelined stages may wait between each other.
        timings["total"] = sum(timings.values())
        return DepthFrame(
            seq,
            ts_ns,
            out.depth,
            out.range,
            out.disparity,
            out.valid,
            out.confidence,
            rect.left_rect,
            rect.right_rect,
            timings,
            matched.searched,
        )

    def process(self, left: U8, right: U8, seq: int = 0, ts_ns: int = 0) -> DepthFrame:
        """Depth for one fisheye pair (see :class:`DepthFrame`): :meth:`rectify`, :meth:`match`
        and :meth:`postprocess` in one go; concurrent callers are served one after the other."""
        with self._process_lock:
            return self.postprocess(self.match(self.rectify(left, right)), seq, ts_ns)

    # ----- outputs -----------------------------------------------------------------------------
    def point_cloud(
        self, frame: DepthFrame, stride: int = 1, *, image: U8 | None = None
    ) -> tuple[NDArray[np.float32], U8]:
        """Points (N, 3) float32 in the rig frame and their colours (N, 3) uint8 RGB (gray
        images give gray colours), every ``stride``-th pixel of each axis. Colours come from
        ``image`` (the left VPC image, (H, W[, 3]) uint8) or else ``frame.left_rect``."""
        pair = self.pair
        pts, idx = range_points(frame.range, pair.camera, pair.T_rig_rect[pair.left], stride)
        img = frame.left_rect if image is None else image
        if img.shape[:2] != frame.depth.shape:
            raise PipelineError(
                f"point_cloud: colour image is {img.shape[1]}x{img.shape[0]}, depth is "
                f"{frame.depth.shape[1]}x{frame.depth.shape[0]}"
            )
        if img.ndim == 2:
            colors = np.repeat(img.reshape(-1)[idx][:, None], 3, axis=1)
        else:
            colors = img.reshape(-1, 3)[idx][:, ::-1]  # BGR -> RGB
        return pts, np.ascontiguousarray(colors)

    def footprint(self, camera: str, samples: int = 64) -> NDArray[np.float64]:
        """The rectified view's outline traced in ``camera``'s fisheye image: (M, 2) pixels, a
        closed polyline of the outline points the lens sees. The pinhole pair's outline is its
        image border (top, right, bottom, left edges, ``samples`` points each); the lat-lon
        pair's, whose image corners no lens sees, the border of the overlap (where both lenses
        see, ``4·samples`` points). For the dashboard overlay."""
        geometry = self._in_effect.geometry
        if camera not in geometry.lut_info:
            raise ConfigError(f"footprint: no camera {camera!r} in the VPC pair ({', '.join(self.names)})")
        if samples < 2:
            raise ConfigError(f"footprint: samples must be >= 2, got {samples}")
        pair = geometry.pair
        c = pair.camera
        if isinstance(c, LatLonModel):
            luts = geometry.luts
            outline = region_outline(luts[pair.left].valid & luts[pair.right].valid, 4 * samples)
        else:
            outline = image_border(c.width, c.height, samples)
        rays, _ = c.unproject(outline, in_image=False)
        pix, ok = geometry.rig.cameras[camera].project(rays @ pair.R_cam_rect[camera].T, in_image=False)
        return pix[ok]
