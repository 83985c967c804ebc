"""The depth pipeline: fisheye pair → VPC pair (cached LUT remap) → disparity → depth.

``DepthPipeline(rig)`` builds (or loads from the cache) one LUT per camera for the VPC pair of
:func:`rig.rectified.design_rectified_pair`; ``process(left, right)`` runs the stages configured by
:class:`rig.stereo.StereoParams` and returns a :class:`DepthFrame` with per-stage timings.

``process`` is three stages that a pipelined caller (the service's worker) may run on three
threads, frame N+1's stage 1 while frame N is in stage 2 or 3: :meth:`rectify` (LUT remap + gray;
thread-safe), :meth:`match` (the OpenCV matcher's parallel part; serialised) and :meth:`finish`
(its speckle removal, refinement, filters, confidence, depth; serialised, in frame order for the
temporal filter).

Thread safety: ``process`` may be called from several threads (a lock serialises them);
``update_stereo`` may be called from any thread: it builds a new matcher and swaps it in
atomically, and the next frame to reach :meth:`match` uses it. ``replace_rig`` likewise builds
the lookup tables of a corrected calibration (the online rectification refinement) on the
calling thread and swaps them in as one :class:`PairGeometry`: a pair is rectified and finished
with one geometry, whichever it started with, so no frame mixes two or is dropped.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
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
from rig.rectified import RectifiedCamera, RectifiedPair, RectifiedPairConfig, design_rectified_pair
from rig.stereo import MatchedDisparity, SeenColumns, StereoMatcher, StereoParams, UnfilteredDisparity

__all__ = [
    "DepthFrame",
    "DepthPipeline",
    "MatchedImages",
    "PairGeometry",
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
    ``left_rect``/``right_rect`` uint8, gray or BGR like the input; ``timings_ms`` per stage
    (remap, match, refine, filters, depth, total).
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


@dataclass(frozen=True)
class PairGeometry:
    """What the calibration fixes for the depth pipeline: the rig, its VPC pair, one lookup table
    per camera (and where it came from), the masks the finish stage applies (None where a
    table sees its whole VPC) and the columns each lens sees, which bound the matching (None:
    all of them)."""

    rig: Rig
    pair: RectifiedPair
    lut_info: dict[str, CachedLut]
    left_mask: NDArray[np.bool_] | None
    right_mask: NDArray[np.bool_] | None
    seen: SeenColumns | None = None

    @property
    def luts(self) -> dict[str, Lut]:
        return {n: info.lut for n, info in self.lut_info.items()}

    @classmethod
    def build(
        cls,
        rig: Rig,
        config: RectifiedPairConfig,
        cache: LutCache,
        blind_band_px: int = 0,
        camera: RectifiedCamera | None = None,
        luts: Mapping[str, CachedLut] | None = None,
    ) -> PairGeometry:
        """The pair of ``rig`` for ``config`` (a lat-lon field's default widened by the matcher's
        ``blind_band_px`` unmatched columns), tables from (or built into) ``cache``. ``camera``
        keeps a given rectified image grid (a corrected calibration moves the lenses' overlap,
        and with it a lat-lon field's size, which frames in flight and the finish stage share).
        ``luts``: the tables handed in instead (built once elsewhere for this calibration, e.g.
        shipped to a cluster's workers)."""
        pair = design_rectified_pair(rig, config, blind_band_px=blind_band_px)
        if camera is not None:
            pair = replace(pair, camera=camera)
        info = {
            n: _shipped(n, luts, pair)
            if luts is not None
            else cache.get(rig.cameras[n], pair.R_cam_rect[n], pair.camera)
            for n in (pair.left, pair.right)
        }
        left, right = info[pair.left].lut, info[pair.right].lut
        whole = left.valid_fraction == 1.0 and right.valid_fraction == 1.0
        return cls(
            rig,
            pair,
            info,
            None if left.valid_fraction == 1.0 else left.valid,
            None if right.valid_fraction == 1.0 else right.valid,
            None if whole else SeenColumns.of(left.valid, right.valid),
        )


def _shipped(name: str, luts: Mapping[str, CachedLut], pair: RectifiedPair) -> CachedLut:
    """Camera ``name``'s table as handed in, checked against the pair's image size."""
    info = luts.get(name)
    expected = (pair.camera.height, pair.camera.width)
    if info is None or info.lut.shape != expected:
        got = "none" if info is None else "x".join(map(str, info.lut.shape[::-1]))
        raise ConfigError(
            f"lookup table of camera {name!r}: {got} handed in for a {expected[1]}x{expected[0]} VPC"
        )
    return info


@dataclass
class RectifiedImages:
    """Output of :meth:`DepthPipeline.rectify`: the VPC images (H, W[, 3]) uint8, their gray
    versions (H, W) uint8 (the same arrays for gray input), the stage's time and the geometry
    that made them (None: the pipeline's current one)."""

    left_rect: U8
    right_rect: U8
    left_gray: U8
    right_gray: U8
    remap_ms: float
    geometry: PairGeometry | None = None


@dataclass
class MatchedImages:
    """Output of :meth:`DepthPipeline.match`: the matcher's output before its speckle removal
    and the matcher that made it (its parameters drive :meth:`DepthPipeline.finish`, which
    removes the speckles in place: a second ``finish`` of the same pair finds none left)."""

    rectified: RectifiedImages
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
        vpc: RectifiedPairConfig | None = None,
        stereo: StereoParams | None = None,
        cache_dir: str | Path | None = None,
        *,
        tune_malloc: bool = True,
        luts: Mapping[str, CachedLut] | None = None,
    ) -> None:
        if tune_malloc:
            tune_allocator()
        self.pair_config = vpc or RectifiedPairConfig()
        params = stereo or StereoParams()
        # A lat-lon field's default leaves room for the matcher's unmatched columns.
        self._blind_band_px = params.blind_band_px
        self.cache = LutCache(cache_dir)
        self._geometry = PairGeometry.build(rig, self.pair_config, self.cache, self._blind_band_px, luts=luts)
        self.names = (self.pair.left, self.pair.right)
        self._report_field(self._geometry)
        self._swap_lock = threading.Lock()
        self._process_lock = threading.Lock()
        self._match_lock = threading.Lock()
        self._finish_lock = threading.Lock()
        self._check_params(params)
        self._matcher = StereoMatcher(params)
        self._finish = FinishStage(self.pair.camera, self.baseline_m, self._matcher)

    # ----- configuration -----------------------------------------------------------------------
    @property
    def geometry(self) -> PairGeometry:
        """The current geometry (take it once per pair: :meth:`replace_rig` may swap it)."""
        return self._geometry

    @property
    def rig(self) -> Rig:
        return self._geometry.rig

    @property
    def pair(self) -> RectifiedPair:
        return self._geometry.pair

    @property
    def baseline_m(self) -> float:
        return self._geometry.pair.baseline_m

    @property
    def lut_info(self) -> dict[str, CachedLut]:
        return self._geometry.lut_info

    @property
    def luts(self) -> dict[str, Lut]:
        return self._geometry.luts

    @property
    def valid_fraction(self) -> dict[str, float]:
        return {n: lut.valid_fraction for n, lut in self.luts.items()}

    @property
    def _latlon(self) -> bool:
        return isinstance(self.pair.camera, LatLonModel)

    def _report_field(self, geometry: PairGeometry) -> None:
        """Log what the rectified view leaves out: for the pinhole pair the share of its pixels a
        lens does not see (an unusual VPC); the lat-lon field is the lenses' overlap by design,
        an explicit field wider than it is clipped (:attr:`RectifiedPair.field_note`)."""
        pair = geometry.pair
        c = pair.camera
        fractions = {n: info.lut.valid_fraction for n, info in geometry.lut_info.items()}
        if pair.field_note:
            log.warning("%s", pair.field_note)
        if isinstance(c, LatLonModel):
            log.info(
                "lat-lon pair %dx%d, %.3f px/deg, %d unmatched columns on the left; the lenses see "
                "%s / %s of its pixels",
                c.width,
                c.height,
                np.radians(c.fx),
                self._blind_band_px,
                *(percent_valid(fractions[n]) for n in (pair.left, pair.right)),
            )
            return
        v = self.pair_config
        for name, frac in fractions.items():
            if frac < 1.0:
                log.warning(
                    "VPC (%dx%d, hfov %.1f°, yaw %.1f°, pitch %.1f°) leaves camera '%s''s field: "
                    "only %s of its pixels are valid",
                    v.width, v.height, v.hfov_deg, v.yaw_deg, v.pitch_deg, name, percent_valid(frac),
                )  # fmt: skip

    def replace_rig(self, rig: Rig) -> PairGeometry:
        """Swap in a corrected calibration of the same cameras and baseline length (the online
        rectification refinement): its tables are built (or read from the cache) here, then
        swapped in at once; pairs already rectified finish with the geometry they began with.
        ConfigError when the lenses or the baseline's length differ (depth would change scale)."""
        old = self._geometry
        for name in self.names:
            if name not in rig.cameras or rig.cameras[name].to_dict() != old.rig.cameras[name].to_dict():
                raise ConfigError(
                    f"replace_rig: camera {name!r} is not the same lens; restart with the new calibration"
                )
        geometry = PairGeometry.build(rig, self.pair_config, self.cache, self._blind_band_px, old.pair.camera)
        if abs(geometry.pair.baseline_m - old.pair.baseline_m) > 1e-9 * old.pair.baseline_m:
            raise ConfigError(
                f"replace_rig: the baseline changes from {old.pair.baseline_m:.6f} m to "
                f"{geometry.pair.baseline_m:.6f} m; restart with the new calibration"
            )
        self._report_field(geometry)
        with self._swap_lock:
            self._geometry = geometry
        return geometry

    @property
    def stereo(self) -> StereoParams:
        return self._matcher.params

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

    def temporal_state(self) -> F32 | None:
        """The temporal filter's history after the last finished frame (None: empty), to carry
        into another pipeline of the same settings (the next chunk of a recording)."""
        with self._finish_lock:
            return self._finish.temporal_state

    def restore_temporal_state(self, state: F32 | None) -> None:
        """Continue from ``state`` (:meth:`temporal_state` of another pipeline; None: start a
        new history, as at the start of a recording)."""
        with self._finish_lock:
            self._finish.temporal_state = state

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
        vpc = (geometry or self._geometry).lut_info[name].lut.remap(image)
        return vpc, _gray(vpc)

    def remap(self, left: U8, right: U8) -> tuple[U8, U8]:
        """The VPC pair from a fisheye pair (fixed-point bilinear remap, black outside the lens)."""
        geometry = self._geometry
        pair = geometry.pair
        self._check_input(pair.left, left)
        self._check_input(pair.right, right)
        return geometry.lut_info[pair.left].lut.remap(left), geometry.lut_info[pair.right].lut.remap(right)

    def rectify(self, left: U8, right: U8) -> RectifiedImages:
        """Stage 1 of :meth:`process`: the VPC pair and its gray images (thread-safe)."""
        t0 = time.perf_counter()
        geometry = self._geometry
        left_rect, left_gray = self.rectify_camera(geometry.pair.left, left, geometry)
        right_rect, right_gray = self.rectify_camera(geometry.pair.right, right, geometry)
        ms = (time.perf_counter() - t0) * 1e3
        return RectifiedImages(left_rect, right_rect, left_gray, right_gray, ms, geometry)

    def match(self, rect: RectifiedImages) -> MatchedImages:
        """Stage 2 of :meth:`process`: the current matcher's OpenCV call (its parallel part; the
        speckle removal after it is :meth:`finish`'s, so that it overlaps the next pair's call).
        Callers are serialised (an OpenCV matcher keeps scratch buffers)."""
        with self._match_lock:
            with self._swap_lock:
                matcher = self._matcher
            seen = (rect.geometry or self._geometry).seen
            t0 = time.perf_counter()
            unfiltered = matcher.compute(rect.left_gray, rect.right_gray, seen)
            return MatchedImages(rect, matcher, unfiltered, (time.perf_counter() - t0) * 1e3)

    def _disparity(self, matched: MatchedImages) -> MatchedDisparity:
        """The matcher's disparity of ``matched`` (speckles removed), LUT masks applied."""
        raw = matched.matcher.finish(matched.unfiltered)
        disparity, valid = raw.disparity, raw.valid
        geometry = matched.rectified.geometry or self._geometry
        left_mask, right_mask = geometry.left_mask, geometry.right_mask
        if left_mask is not None:
            valid &= left_mask
        if right_mask is not None:
            valid = visible_in_right(disparity, valid, right_mask)
        if left_mask is not None or right_mask is not None:
            fill_where(disparity, np.nan, ~valid)
        return MatchedDisparity(disparity, valid)

    def finish(self, matched: MatchedImages, seq: int = 0, ts_ns: int = 0) -> DepthFrame:
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
            rect.left_rect,
            rect.right_rect,
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
        geometry = self._geometry
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
