"""The depth pipeline: fisheye pair → VPC pair (cached LUT remap) → disparity → depth.

``DepthPipeline(rig)`` builds (or loads from the cache) one LUT per camera for the VPC pair of
:func:`rig.vpc.design_vpc_pair`; ``process(left, right)`` runs the stages configured by
:class:`rig.stereo.StereoParams` and returns a :class:`DepthFrame` with per-stage timings.

``process`` is three stages that a pipelined caller (the service's worker) may run on three
threads, frame N+1's stage 1 while frame N is in stage 2 or 3: :meth:`rectify` (LUT remap + gray;
thread-safe), :meth:`match` (the OpenCV matcher's parallel part; serialised) and :meth:`finish`
(its speckle removal, refinement, filters, confidence, depth; serialised, in frame order for the
temporal filter).

Thread safety: ``process`` may be called from several threads (a lock serialises them);
``update_stereo`` may be called from any thread: it builds a new matcher and swaps it in
atomically, and the next frame to reach :meth:`match` uses it.
"""

from __future__ import annotations

import logging
import threading
import time
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
from rig.finish import FinishStage
from rig.heap import tune_allocator
from rig.lut import Lut, percent_valid
from rig.lut_cache import CachedLut, LutCache
from rig.stereo import MatchedDisparity, StereoMatcher, StereoParams, UnfilteredDisparity
from rig.vpc import VpcConfig, VpcPair, design_vpc_pair

__all__ = ["DepthFrame", "DepthPipeline", "MatchedPair", "RectifiedPair", "tune_allocator"]

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
    ``left_vpc``/``right_vpc`` uint8, gray or BGR like the input; ``timings_ms`` per stage
    (remap, match, refine, filters, depth, total).
    """

    seq: int
    ts_ns: int
    depth: F32
    range: F32
    disparity: F32
    valid: NDArray[np.bool_]
    confidence: F32 | None
    left_vpc: U8
    right_vpc: U8
    timings_ms: dict[str, float] = field(default_factory=dict)


@dataclass
class RectifiedPair:
    """Output of :meth:`DepthPipeline.rectify`: the VPC images (H, W[, 3]) uint8, their gray
    versions (H, W) uint8 (the same arrays for gray input) and the stage's time."""

    left_vpc: U8
    right_vpc: U8
    left_gray: U8
    right_gray: U8
    remap_ms: float


@dataclass
class MatchedPair:
    """Output of :meth:`DepthPipeline.match`: the matcher's output before its speckle removal
    and the matcher that made it (its parameters drive :meth:`DepthPipeline.finish`, which
    removes the speckles in place: a second ``finish`` of the same pair finds none left)."""

    rectified: RectifiedPair
    matcher: StereoMatcher
    unfiltered: UnfilteredDisparity
    match_ms: float


def _gray(img: U8) -> U8:
    if img.ndim == 2:
        return img
    return np.asarray(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), dtype=np.uint8)


class DepthPipeline:
    """Depth from a fisheye pair of ``rig`` (see module doc). ``tune_malloc`` calls
    :func:`tune_allocator` (process-wide; the pipeline is what the process is for)."""

    def __init__(
        self,
        rig: Rig,
        vpc: VpcConfig | None = None,
        stereo: StereoParams | None = None,
        cache_dir: str | Path | None = None,
        *,
        tune_malloc: bool = True,
    ) -> None:
        if tune_malloc:
            tune_allocator()
        self.rig = rig
        self.vpc_config = vpc or VpcConfig()
        params = stereo or StereoParams()
        # A lat-lon field's default leaves room for the matcher's unmatched columns.
        self.pair: VpcPair = design_vpc_pair(rig, self.vpc_config, blind_band_px=params.blind_band_px)
        self.baseline_m = self.pair.baseline_m
        self.cache = LutCache(cache_dir)
        self.names = (self.pair.left, self.pair.right)
        self.lut_info: dict[str, CachedLut] = {}
        for name in self.names:
            self.lut_info[name] = self.cache.get(
                rig.cameras[name], self.pair.R_cam_vpc[name], self.pair.camera
            )
        self.luts: dict[str, Lut] = {n: info.lut for n, info in self.lut_info.items()}
        self.valid_fraction = {n: lut.valid_fraction for n, lut in self.luts.items()}
        self._latlon = isinstance(self.pair.camera, LatLonModel)
        self._blind_band_px = params.blind_band_px
        self._report_field()
        left_lut, right_lut = self.luts[self.pair.left], self.luts[self.pair.right]
        # Masks are only applied when they exclude something (the usual VPC sees all valid).
        self._left_mask = None if left_lut.valid_fraction == 1.0 else left_lut.valid
        self._right_mask = None if right_lut.valid_fraction == 1.0 else right_lut.valid
        self._swap_lock = threading.Lock()
        self._process_lock = threading.Lock()
        self._match_lock = threading.Lock()
        self._finish_lock = threading.Lock()
        self._check_params(params)
        self._matcher = StereoMatcher(params)
        self._finish = FinishStage(self.pair.camera, self.baseline_m, self._matcher)

    # ----- configuration -----------------------------------------------------------------------
    @property
    def stereo(self) -> StereoParams:
        return self._matcher.params

    def _report_field(self) -> None:
        """Log what the rectified view leaves out: for the pinhole pair the share of its pixels a
        lens does not see (an unusual VPC); the lat-lon field is the lenses' overlap by design,
        an explicit field wider than it is clipped (:attr:`VpcPair.field_note`)."""
        c = self.pair.camera
        if self.pair.field_note:
            log.warning("%s", self.pair.field_note)
        if self._latlon:
            log.info(
                "lat-lon pair %dx%d, %.3f px/deg, %d unmatched columns on the left; the lenses see "
                "%s / %s of its pixels",
                c.width,
                c.height,
                np.radians(c.fx),
                self._blind_band_px,
                *(percent_valid(self.valid_fraction[n]) for n in self.names),
            )
            return
        for name, frac in self.valid_fraction.items():
            if frac < 1.0:
                log.warning(
                    "VPC (%dx%d, hfov %.1f°, yaw %.1f°, pitch %.1f°) leaves camera '%s''s field: "
                    "only %s of its pixels are valid",
                    self.vpc_config.width,
                    self.vpc_config.height,
                    self.vpc_config.hfov_deg,
                    self.vpc_config.yaw_deg,
                    self.vpc_config.pitch_deg,
                    name,
                    percent_valid(frac),
                )

    def _check_params(self, params: StereoParams) -> None:
        width = self.pair.camera.width
        if params.disparity_range + max(params.min_disparity, 0) >= width:
            raise ConfigError(
                f"stereo: disparity_range {params.disparity_range} + min_disparity {params.min_disparity} "
                f"must be below the VPC width {width}"
            )

    def update_stereo(self, params: StereoParams) -> None:
        """Swap in new stereo parameters (thread-safe; takes effect at the next frame)."""
        self._check_params(params)
        matcher = StereoMatcher(params)
        if self._latlon and params.blind_band_px > self._blind_band_px:
            log.warning(
                "stereo: the lat-lon field leaves room for %d unmatched columns, the new settings "
                "leave %d: the overlap's leftmost %d columns get no range until the service restarts",
                self._blind_band_px,
                params.blind_band_px,
                params.blind_band_px - self._blind_band_px,
            )
        with self._swap_lock:
            self._matcher = matcher

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

    def rectify_camera(self, name: str, image: U8) -> tuple[U8, U8]:
        """One camera's VPC image (gray or BGR like ``image``) and its gray version, which is
        the same array for gray input. Thread-safe: reads only the camera's LUT."""
        self._check_input(name, image)
        vpc = self.luts[name].remap(image)
        return vpc, _gray(vpc)

    def remap(self, left: U8, right: U8) -> tuple[U8, U8]:
        """The VPC pair from a fisheye pair (fixed-point bilinear remap, black outside the lens)."""
        self._check_input(self.pair.left, left)
        self._check_input(self.pair.right, right)
        return self.luts[self.pair.left].remap(left), self.luts[self.pair.right].remap(right)

    def rectify(self, left: U8, right: U8) -> RectifiedPair:
        """Stage 1 of :meth:`process`: the VPC pair and its gray images (thread-safe)."""
        t0 = time.perf_counter()
        left_vpc, left_gray = self.rectify_camera(self.pair.left, left)
        right_vpc, right_gray = self.rectify_camera(self.pair.right, right)
        return RectifiedPair(left_vpc, right_vpc, left_gray, right_gray, (time.perf_counter() - t0) * 1e3)

    def match(self, rect: RectifiedPair) -> MatchedPair:
        """Stage 2 of :meth:`process`: the current matcher's OpenCV call (its parallel part; the
        speckle removal after it is :meth:`finish`'s, so that it overlaps the next pair's call).
        Callers are serialised (an OpenCV matcher keeps scratch buffers)."""
        with self._match_lock:
            with self._swap_lock:
                matcher = self._matcher
            t0 = time.perf_counter()
            unfiltered = matcher.compute(rect.left_gray, rect.right_gray)
            return MatchedPair(rect, matcher, unfiltered, (time.perf_counter() - t0) * 1e3)

    def _disparity(self, matched: MatchedPair) -> MatchedDisparity:
        """The matcher's disparity of ``matched`` (speckles removed), LUT masks applied."""
        raw = matched.matcher.finish(matched.unfiltered)
        disparity, valid = raw.disparity, raw.valid
        if self._left_mask is not None:
            valid &= self._left_mask
        if self._right_mask is not None:
            valid = visible_in_right(disparity, valid, self._right_mask)
        if self._left_mask is not None or self._right_mask is not None:
            fill_where(disparity, np.nan, ~valid)
        return MatchedDisparity(disparity, valid)

    def finish(self, matched: MatchedPair, seq: int = 0, ts_ns: int = 0) -> DepthFrame:
        """Stage 3 of :meth:`process`: the matcher's speckle removal, then refinement, filters,
        confidence and depth with the parameters of the matcher that made ``matched``
        (:class:`rig.finish.FinishStage`, in row bands across the cores). Call in frame order
        (the temporal filter's history); callers are serialised."""
        rect = matched.rectified
        with self._finish_lock:
            out, speckle_ms, stage = self._finish(
                matched.matcher, rect.left_gray, rect.right_gray, lambda: self._disparity(matched)
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
            rect.left_vpc,
            rect.right_vpc,
            timings,
        )

    def process(self, left: U8, right: U8, seq: int = 0, ts_ns: int = 0) -> DepthFrame:
        """Depth for one fisheye pair (see :class:`DepthFrame`): :meth:`rectify`, :meth:`match`
        and :meth:`finish` in one go; concurrent callers are served one after the other."""
        with self._process_lock:
            return self.finish(self.match(self.rectify(left, right)), seq, ts_ns)

    # ----- outputs -----------------------------------------------------------------------------
    def point_cloud(
        self, frame: DepthFrame, stride: int = 1, *, image: U8 | None = None
    ) -> tuple[NDArray[np.float32], U8]:
        """Points (N, 3) float32 in the rig frame and their colours (N, 3) uint8 RGB (gray
        images give gray colours), every ``stride``-th pixel of each axis. Colours come from
        ``image`` (the left VPC image, (H, W[, 3]) uint8) or else ``frame.left_vpc``."""
        pts, idx = range_points(frame.range, self.pair.camera, self.pair.T_rig_vpc[self.pair.left], stride)
        img = frame.left_vpc if image is None else image
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
        if camera not in self.luts:
            raise ConfigError(f"footprint: no camera {camera!r} in the VPC pair ({', '.join(self.names)})")
        if samples < 2:
            raise ConfigError(f"footprint: samples must be >= 2, got {samples}")
        c = self.pair.camera
        if self._latlon:
            both = self.luts[self.pair.left].valid & self.luts[self.pair.right].valid
            outline = region_outline(both, 4 * samples)
        else:
            outline = image_border(c.width, c.height, samples)
        rays, _ = c.unproject(outline, in_image=False)
        pix, ok = self.rig.cameras[camera].project(rays @ self.pair.R_cam_vpc[camera].T, in_image=False)
        return pix[ok]
