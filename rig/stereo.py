"""Stereo matching on the rectified VPC pair (see docs/stereo.md).

OpenCV ``StereoSGBM`` (any of its modes) or ``StereoBM``, configured with the parameter names
of ROS ``stereo_image_proc``'s disparity node, searching the whole range at full resolution (the
exact search, the default) or at a coarse level and then at full resolution in narrow bands
(``coarse_to_fine: true``, :mod:`rig.coarse_to_fine`), plus our own stages: subpixel
refinement and a confidence map (:mod:`rig.subpixel`), a full left-right check, median and
temporal filters (:mod:`rig.filters`). Every stage is configuration; none is a code fork.

Default choices (measured on the virtual environment; see docs/stereo.md, whose tables
``python -m bench.phantoms`` and ``pytest -s tests/rig/test_stereo_render.py tests/rig/test_filters.py``
print): SGBM_3WAY, a 7 px window, speckle removal, our subpixel refinement with a 15 px window, a
5×5 median and the confidence map on, as measured for accuracy; 96 disparities and the full
left-right check on, chosen against *phantom obstacles*: a repetitive or weak texture matched with
its next repeat gives a disparity one period too large, a near surface that is not there. Fewer
disparities leave fewer wrong periods within reach, and the left-right check removes most of
the rest; the price is the nearest depth (fx·B/96 at the VPC's fx) and a second matcher run,
at half resolution (:mod:`rig.half_check`; both measured in docs/stereo.md). The temporal
filter is off (it lags moving scenes). The coarse-to-fine search costs about half the
matching's CPU; since the normalised match input it is measurably worse than the exact search
on the real ring and the lat-lon renders' phantoms (docs/stereo.md, "Coarse-to-fine search"),
so it is off by default.
"""

from __future__ import annotations

import math
from concurrent.futures import Executor
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import ConfigDict, Field, field_validator, model_validator

from rig.coarse_to_fine import CoarseToFine, FineLevel, downsample
from rig.disparity import MatchedDisparity, SeenColumns, UnfilteredDisparity
from rig.errors import PipelineError
from rig.filters import fill_where, left_right_consistent
from rig.half_check import half_mirrored_view
from rig.settings_model import SettingsModel
from rig.temporal_prior import LastSearch

__all__ = [
    "COARSE_HALF_UP_TO",
    "COARSE_P2_FACTOR",
    "COST_PER_WINDOW_PIXEL",
    "HALF_CHECK_TOLERANCE",
    "MAX_PATH_COST",
    "SGBM_MODES",
    "MatchedDisparity",
    "SeenColumns",
    "StereoMatcher",
    "StereoParams",
    "UnfilteredDisparity",
    "create_opencv_matcher",
]

U8 = NDArray[np.uint8]
F32 = NDArray[np.float32]

SgbmMode = Literal["sgbm", "hh", "3way", "hh4"]
SGBM_MODES: dict[str, int] = {
    "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
    "hh": cv2.STEREO_SGBM_MODE_HH,
    "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    "hh4": cv2.STEREO_SGBM_MODE_HH4,
}
# ROS 2's disparity node numbers the SGBM variants 0..3 in this order.
_ROS_SGBM_MODE = ("sgbm", "hh", "3way", "hh4")


#: SGBM's cost type is int16: the largest path cost that does not saturate.
MAX_PATH_COST = 32767
#: A window pixel's share of the matching cost at which SGBM's path costs saturate, measured on
#: renders (tests/rig/test_stereo_limits.py): with P2 + 16·w² above 32767 nearly every disparity
#: is wrong (w = 27 with the default penalties; P2 = 32000 with a 7 px window).
COST_PER_WINDOW_PIXEL = 16
#: The coarse-to-fine search's coarse level is 1/2 resolution up to this many disparities, 1/4 beyond.
COARSE_HALF_UP_TO = 128
#: The coarse level's P2 over the full resolution's: a step of one coarse pixel is ``scale`` full
#: ones, and a stiffer coarse level keeps repetitive texture from locking onto the wrong period
#: (measured: docs/stereo.md, "Coarse-to-fine search").
COARSE_P2_FACTOR = 4
#: The left-right check's tolerance at half resolution over ``lr_max_diff``: the check compares a
#: full-resolution disparity with one of pixels twice the size, and its tolerance scales with the
#: mean of the two views' pixel sizes, (1 + 2) / 2 (docs/stereo.md, "Left-right check at half
#: resolution", measured on the real ring).
HALF_CHECK_TOLERANCE = 1.5


class StereoParams(SettingsModel):
    """Matcher and post-filter configuration. Names and meanings follow ROS stereo_image_proc
    (``stereo_algorithm`` 0 = BM, 1 = SGBM; ``full_dp`` = SGBM's full 8-path HH mode); the
    fields after ``full_dp`` are ours."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    stereo_algorithm: Literal[0, 1] = Field(1, description="0 = block matching (BM), 1 = SGBM")
    sgbm_mode: SgbmMode = Field("3way", description="SGBM variant: sgbm, hh, 3way, hh4 (or ROS 0..3)")
    prefilter_size: int = Field(9, ge=5, le=255, description="BM normalisation window (odd, px)")
    prefilter_cap: int = Field(31, ge=1, le=63, description="bound on prefiltered pixel values")
    correlation_window_size: int = Field(7, ge=1, le=255, description="matching window (odd, px)")
    min_disparity: int = Field(0, ge=-2048, le=2048, description="smallest disparity searched (px)")
    disparity_range: int = Field(
        96, ge=16, le=4096, description="disparities searched (multiple of 16); nearest depth fx·B/range"
    )
    min_range_m: float | None = Field(
        None,
        gt=0.0,
        le=1000.0,
        description="nearest range to reach: the search widens to it (rig.reach); null = off",
    )
    # OpenCV 5.0 SGBM_3WAY divides by zero (SIGFPE, the process dies) at a ratio of 100 (rounded):
    # this bound is the only guard against it, for the settings, the command line and PATCH /config.
    uniqueness_ratio: float = Field(10.0, ge=0.0, lt=99.5, description="best must beat 2nd by this %")
    texture_threshold: int = Field(10, ge=0, le=10000, description="BM: minimum window texture")
    speckle_size: int = Field(100, ge=0, le=10000, description="remove blobs smaller than this (0 = off)")
    speckle_range: int = Field(2, ge=0, le=64, description="max disparity step inside a blob (px)")
    disp12_max_diff: int = Field(1, ge=-1, le=4096, description="matcher's internal L-R check (px, -1 off)")
    P1: float = Field(0.0, ge=0.0, le=1e7, description="SGBM smoothness penalty, ±1 px steps (0 = 8·w²)")
    P2: float = Field(0.0, ge=0.0, le=1e7, description="SGBM smoothness penalty, larger steps (0 = 32·w²)")
    full_dp: bool = Field(False, description="SGBM full 8-direction dynamic programming (= mode hh)")
    match_blur_sigma: float = Field(
        0.0, ge=0.0, le=8.0, description="blur of both views before matching (px; 0 = off; rig.match_input)"
    )
    match_normalise_window: int = Field(
        31, ge=0, le=255, description="local contrast normalisation before matching (odd px; 0 = off)"
    )
    match_normalise_eps: float = Field(
        16.0, gt=0.0, le=255.0, description="grey levels added to the local σ: flat regions stay flat"
    )
    subpixel: bool = Field(True, description="gradient-based subpixel refinement (rig.subpixel)")
    subpixel_window: int = Field(15, ge=3, le=31, description="refinement window (odd, px)")
    lr_check: bool = Field(True, description="full left-right consistency check (2nd matcher run)")
    lr_max_diff: float = Field(1.0, gt=0.0, le=16.0, description="LR check tolerance (px; x1.5 at half res.)")
    median: Literal[0, 3, 5] = Field(5, description="median filter on disparity (0 = off)")
    temporal_alpha: float = Field(0.0, ge=0.0, lt=1.0, description="weight of the past frame (0 = off)")
    temporal_reset: float = Field(1.0, gt=0.0, le=64.0, description="disparity change that restarts (px)")
    confidence: bool = Field(True, description="per-pixel confidence map in [0, 1]")
    confidence_sigma: float = Field(0.1, ge=1e-4, le=10.0, description="predicted σ_d giving conf. 1/e")
    # The coarse-to-fine search (rig.coarse_to_fine; docs/stereo.md, "Coarse-to-fine search").
    coarse_to_fine: bool = Field(False, description="whole range at a coarse level, full resolution in bands")
    coarse_scale: Literal[0, 2, 4] = Field(0, description="coarse level 1/2 or 1/4 (0: 1/2 up to 128 disp.)")
    temporal_prior: bool = Field(True, description="live: what did not change keeps its last search")
    coarse_confirm: bool = Field(
        False, description="coarse level also on the views not normalised: keep what both find, inward"
    )
    lr_check_scale: Literal[1, 2] = Field(
        2, description="the LR check's mirrored search at full (1) or half (2) resolution (rig.half_check)"
    )

    @field_validator("sgbm_mode", mode="before")
    @classmethod
    def _ros_mode_number(cls, v: Any) -> Any:
        if isinstance(v, int) and not isinstance(v, bool) and 0 <= v < len(_ROS_SGBM_MODE):
            return _ROS_SGBM_MODE[v]
        return v.lower() if isinstance(v, str) else v

    @model_validator(mode="after")
    def _consistent(self) -> StereoParams:
        problems = [
            f"{name} must be odd, got {getattr(self, name)}"
            for name in ("correlation_window_size", "prefilter_size", "subpixel_window")
            if getattr(self, name) % 2 == 0
        ]
        if self.match_normalise_window and self.match_normalise_window % 2 == 0:
            problems.append(f"match_normalise_window must be 0 or odd, got {self.match_normalise_window}")
        if self.disparity_range % 16:
            problems.append(f"disparity_range must be a multiple of 16, got {self.disparity_range}")
        if self.stereo_algorithm == 0 and self.correlation_window_size < 5:
            problems.append("correlation_window_size must be >= 5 for block matching (BM)")
        if self.full_dp and self.sgbm_mode not in ("sgbm", "hh"):
            problems.append(f"full_dp conflicts with sgbm_mode {self.sgbm_mode!r} (full_dp means 'hh')")
        if self.P2 and self.P1 and self.P2 <= self.P1:
            problems.append(f"P2 ({self.P2}) must be larger than P1 ({self.P1})")
        elif self.stereo_algorithm == 1:
            problems += self._cost_headroom()
        if problems:  # all of them: one answer lists every mistake
            raise ValueError("; ".join(problems))
        return self

    def _cost_headroom(self) -> list[str]:
        """SGBM keeps its path costs in 16 bits: the larger penalty plus a window's matching cost
        must stay below 32768, or the costs saturate and every disparity comes out wrong while
        most pixels still look valid (docs/stereo.md, "What the matcher can do")."""
        w = self.correlation_window_size
        _, p2 = self.penalties()
        need = p2 + COST_PER_WINDOW_PIXEL * w * w
        if need <= MAX_PATH_COST:
            return []
        room = MAX_PATH_COST - COST_PER_WINDOW_PIXEL * w * w
        largest = math.isqrt(MAX_PATH_COST // (COST_PER_WINDOW_PIXEL + 32))
        largest_w = largest if largest % 2 else largest - 1  # windows are odd
        fix = f"P2 at most {room}" if room > 0 else "a smaller window"
        return [
            f"correlation_window_size {w} with P2 {p2} overflows SGBM's 16-bit path costs "
            f"(P2 + {COST_PER_WINDOW_PIXEL}·window² = {need} > {MAX_PATH_COST}): use {fix}, or a window "
            f"of at most {largest_w} with the default penalties"
        ]

    @property
    def blind_band_px(self) -> int:
        """Columns on the left of the image the matcher never matches: OpenCV's matchers start at
        column ``min_disparity + disparity_range`` (a left pixel's match must lie in the image);
        the coarse-to-fine search at its coarse level's (the range rounded up to 16 coarse px)."""
        s = self.coarse_factor
        lo, core, _ = self.coarse_span()
        return max(0, s * (lo + core) if s > 1 else self.min_disparity + self.disparity_range)

    @property
    def coarse_factor(self) -> int:
        """The coarse level's downsampling factor: 1 without the coarse-to-fine search (and for
        block matching, cheap over the whole range); by default 2 up to 128 disparities and 4
        beyond (at most 64 coarse disparities up to 256)."""
        if not self.coarse_to_fine or self.stereo_algorithm != 1:
            return 1
        return self.coarse_scale or (2 if self.disparity_range <= COARSE_HALF_UP_TO else 4)

    @property
    def check_factor(self) -> int:
        """The resolution of the left-right check's mirrored search: 1 (full) or 2 (half,
        ``lr_check_scale``; the exact SGBM search with the check only)."""
        if not self.lr_check or self.coarse_factor > 1 or self.stereo_algorithm != 1:
            return 1
        return self.lr_check_scale

    def lr_tolerance(self, check_scale: int) -> float:
        """The left-right check's tolerance (px) against a mirrored view searched at 1/``check_scale``
        resolution: ``lr_max_diff``, times :data:`HALF_CHECK_TOLERANCE` at half resolution."""
        return self.lr_max_diff * (HALF_CHECK_TOLERANCE if check_scale == 2 else 1.0)

    def coarse_span(self, scale: int | None = None) -> tuple[int, int, int]:
        """The coarse level's smallest disparity, the range that covers this one (rounded up to
        a multiple of 16) and how far it searches beyond that (16 per 64, at least 16: a surface
        found there is too near and gets no depth, rather than a wrong match within the range);
        coarse px. ``scale``: of a level 1/``scale`` (default: the coarse-to-fine search's)."""
        s = scale or self.coarse_factor
        lo = self.min_disparity // s
        core = -(-(-(-(self.min_disparity + self.disparity_range) // s) - lo) // 16) * 16
        return lo, core, -(-core // 64) * 16

    def coarse_level(self, scale: int | None = None, beyond_range: bool = True) -> StereoParams:
        """The parameters of the coarse level's matcher (:meth:`coarse_span`; ``scale`` as
        there, ``beyond_range``: search beyond the range too), speckles of a proportional area
        and a stiffer P2 (:data:`COARSE_P2_FACTOR` times, up to half the path costs' headroom,
        never below this level's). Unchecked: derived."""
        s = scale or self.coarse_factor
        lo, core, beyond = self.coarse_span(s)
        beyond = beyond if beyond_range else 0
        p1, p2 = self.penalties()
        headroom = MAX_PATH_COST - COST_PER_WINDOW_PIXEL * self.correlation_window_size**2
        return self.model_copy(
            update={
                "coarse_to_fine": False,
                "lr_check_scale": 1,
                "min_range_m": None,  # the range is already widened (rig.reach)
                "min_disparity": lo,
                "disparity_range": core + beyond,
                "speckle_size": self.speckle_size // (s * s),
                "P1": float(p1),
                "P2": float(max(p1 + 1, min(COARSE_P2_FACTOR * p2, max(p2, headroom // 2)))),
            }
        )

    def check_level(self) -> StereoParams:
        """The parameters of the half-resolution left-right check's matcher
        (:mod:`rig.half_check`): the coarse level's at 1/2, over the range only (a surface
        nearer than the range then fails the check, as at full resolution)."""
        return self.coarse_level(2, beyond_range=False)

    @property
    def effective_mode(self) -> str:
        return "hh" if self.full_dp else self.sgbm_mode

    def penalties(self, channels: int = 1) -> tuple[int, int]:
        """(P1, P2): as configured, or OpenCV's usual 8·cn·w² / 32·cn·w² when 0."""
        w2 = self.correlation_window_size**2
        p1 = int(self.P1) if self.P1 else 8 * channels * w2
        p2 = int(self.P2) if self.P2 else 32 * channels * w2
        return p1, max(p2, p1 + 1)


def create_opencv_matcher(p: StereoParams) -> Any:
    """The bare OpenCV matcher (``cv2.StereoBM`` or ``cv2.StereoSGBM``) configured by ``p``."""
    if p.stereo_algorithm == 0:
        bm = cv2.StereoBM.create(numDisparities=p.disparity_range, blockSize=p.correlation_window_size)
        bm.setMinDisparity(p.min_disparity)
        bm.setPreFilterType(cv2.STEREO_BM_PREFILTER_NORMALIZED_RESPONSE)
        bm.setPreFilterSize(p.prefilter_size)
        bm.setPreFilterCap(p.prefilter_cap)
        bm.setTextureThreshold(p.texture_threshold)
        bm.setUniquenessRatio(round(p.uniqueness_ratio))
        bm.setSpeckleWindowSize(p.speckle_size)
        bm.setSpeckleRange(p.speckle_range)
        bm.setDisp12MaxDiff(p.disp12_max_diff)
        return bm
    p1, p2 = p.penalties()
    return cv2.StereoSGBM.create(
        minDisparity=p.min_disparity,
        numDisparities=p.disparity_range,
        blockSize=p.correlation_window_size,
        P1=p1,
        P2=p2,
        disp12MaxDiff=p.disp12_max_diff,
        preFilterCap=p.prefilter_cap,
        uniquenessRatio=round(p.uniqueness_ratio),
        speckleWindowSize=p.speckle_size,
        speckleRange=p.speckle_range,
        mode=SGBM_MODES[p.effective_mode],
    )


def _coarse_to_fine(p: StereoParams) -> CoarseToFine | None:
    """The coarse-to-fine search of ``p`` (None: the exact search)."""
    if p.coarse_factor == 1:
        return None
    lo, _, beyond = p.coarse_span()
    d_min, d_max = p.min_disparity, p.min_disparity + p.disparity_range - 1
    level = FineLevel(
        p.coarse_factor, lo, beyond, p.blind_band_px, p.correlation_window_size, d_min, d_max,
        (d_min - 1) * 16, p.lr_check, not p.subpixel, p.coarse_confirm,
    )  # fmt: skip
    coarse = p.coarse_level()
    return CoarseToFine((StereoMatcher(coarse), StereoMatcher(coarse)), level)  # a matcher per view


class StereoMatcher:
    """The matcher of :class:`StereoParams`; ``match`` runs it (and the LR check).

    ``match`` is :meth:`compute` (the search: the coarse-to-fine one, or the OpenCV matcher's
    parallel part) then :meth:`disparity_of` (SGBM's speckle removal, single-threaded, and the
    float conversion), so that a pipelined caller can run the next pair's ``compute`` while this
    one is finished. ``StereoSGBM.compute`` ends with that same ``filterSpeckles`` call on one
    core (~10 ms of a 1280×960 frame); the exact search's result is the bare matcher's bit for
    bit (tested for every mode). :meth:`raw`, :meth:`left_view`, :meth:`mirrored_view` and
    :meth:`right_disparity` are the exact search's whatever the parameters.

    ``compute`` is not safe for concurrent calls (OpenCV matchers keep scratch buffers, the
    coarse-to-fine search its live history); the pipeline swaps whole instances instead of
    mutating one. ``disparity_of`` is.
    """

    def __init__(self, params: StereoParams | None = None) -> None:
        self.params = params or StereoParams()
        # SGBM's speckles are removed in disparity_of(), so OpenCV's own pass is off. StereoBM's pass
        # differs from a later filterSpeckles call (it is cheap there anyway): BM keeps its own.
        self._deferred_speckles = self.params.stereo_algorithm == 1 and self.params.speckle_size > 0
        deferred = {"speckle_size": 0} if self._deferred_speckles else {}
        self._matcher = create_opencv_matcher(self.params.model_copy(update=deferred))
        self.coarse_to_fine_search = _coarse_to_fine(self.params)
        self._half_check = StereoMatcher(self.params.check_level()) if self.params.check_factor == 2 else None
        # The live stream's memory of the exact search (stereo.temporal_prior).
        self.last_search = LastSearch()

    def _compute(self, left: U8, right: U8) -> NDArray[np.int16]:
        try:
            out: NDArray[np.int16] = self._matcher.compute(left, right)
        except cv2.error as err:
            raise PipelineError(f"stereo matcher refused the pair: {' '.join(str(err).split())}") from err
        return out

    def _check(self, left: U8, right: U8) -> None:
        if left.shape != right.shape or left.ndim != 2 or left.dtype != np.uint8:
            raise PipelineError(
                f"matcher needs two gray uint8 images of one size, got {left.shape}/{left.dtype} "
                f"and {right.shape}/{right.dtype}"
            )
        if left.shape[1] <= self.params.disparity_range + max(self.params.min_disparity, 0):
            raise PipelineError(
                f"image width {left.shape[1]} leaves no column for disparity_range "
                f"{self.params.disparity_range} + min_disparity {self.params.min_disparity}"
            )

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
        """The matcher on gray images (H, W) uint8 (and on the mirrored pair with
        ``lr_check``), speckles not yet removed: the coarse-to-fine search
        (:mod:`rig.coarse_to_fine`; ``pool`` its threads, ``temporal_prior`` for a live stream of
        frames in order, when ``stereo.temporal_prior`` allows; ``unnormalised``: the pair
        before :mod:`rig.match_input`'s normalisation, for ``coarse_confirm``) or the OpenCV
        matcher over the whole range (with ``temporal_prior``, a frame in which nothing changed
        keeps its last search: :class:`rig.temporal_prior.LastSearch`). With ``seen``, each run
        matches only the columns its reference lens sees (and those their matches and windows
        need); the others are invalid."""
        self._check(left, right)
        prior = temporal_prior and self.params.temporal_prior
        if self.coarse_to_fine_search is not None:
            return self.coarse_to_fine_search.compute(
                left, right, seen, pool=pool, temporal_prior=prior, unnormalised=unnormalised
            )
        halved = (downsample(left, 2), downsample(right, 2)) if prior else None
        if halved is not None and (kept := self.last_search.kept(*halved)) is not None:
            return kept
        mirrored, unsearched, scale = None, left.shape[1], 1
        if self.params.lr_check:
            mirrored, unsearched, scale = self._checking_view(left, right, seen)
        found = UnfilteredDisparity(
            self.left_view(left, right, seen), mirrored, unsearched, check_scale=scale
        )
        if halved is not None:
            self.last_search.remember(*halved, found)
        return found

    def _checking_view(
        self, left: U8, right: U8, seen: SeenColumns | None
    ) -> tuple[NDArray[np.int16], int, int]:
        """The left-right check's mirrored view, the right image's first column it never matched
        and the resolution it was searched at: the exact search's (1), or at half resolution (2;
        not where the half-resolution images are too narrow for its range)."""
        check = self._half_check
        if check is None or -(-left.shape[1] // 2) <= check.params.blind_band_px:
            return (*self.mirrored_view(left, right, seen), 1)
        coarse_min = check.params.min_disparity
        invalid = (self.params.min_disparity - 1) * 16
        return (*half_mirrored_view(check, coarse_min, (left, right), seen, invalid), 2)

    def forget(self) -> None:
        """Drop the live stream's history (the temporal prior's): the next frame is searched whole."""
        if self.coarse_to_fine_search is not None:
            self.coarse_to_fine_search.prior.reset()
        self.last_search = LastSearch()

    @property
    def searched_fraction(self) -> float:
        """The share of the last live frame the search searched again (the temporal prior's; 1.0
        without it): the coarse-to-fine search's coarse rows, the exact search's whole frame or
        nothing."""
        if self.coarse_to_fine_search is not None:
            return self.coarse_to_fine_search.prior.searched_fraction
        return self.last_search.searched_fraction

    def left_view(self, left: U8, right: U8, seen: SeenColumns | None = None) -> NDArray[np.int16]:
        """The OpenCV matcher's fixed-point disparity of the left view (:meth:`compute`'s exact
        search without the mirrored pair)."""
        return self._compute_columns(left, right, seen.left if seen else (0, left.shape[1]))[0]

    def mirrored_view(
        self, left: U8, right: U8, seen: SeenColumns | None = None
    ) -> tuple[NDArray[np.int16], int]:
        """The OpenCV matcher's fixed-point disparity of the mirrored pair (still mirrored) and
        the right image's first column it never matched (:meth:`compute`'s second run)."""
        width = left.shape[1]
        mirrored, start = self._compute_mirrored(left, right, seen.right if seen else (0, width))
        return mirrored, width - start - self.params.blind_band_px

    def _compute_columns(self, ref: U8, other: U8, seen: tuple[int, int]) -> tuple[NDArray[np.int16], int]:
        """The matcher on the columns of ``ref`` from ``seen[0]`` to ``seen[1]`` (and the ones
        their matches and windows reach), pasted into a full-size disparity that is invalid
        elsewhere; and the first column the crop starts at. Cost grows with the columns
        matched, and a lat-lon pair's right lens sees none of its leftmost ones."""
        p = self.params
        width = ref.shape[1]
        # The window and the pixel cost's neighbour (BM: its prefilter's window too).
        window = max(p.correlation_window_size, p.prefilter_size if p.stereo_algorithm == 0 else 0)
        margin = window // 2 + 1
        # A reference column x is matched against x - d for d in [min, min + range): the crop
        # reaches that far either side (a negative min_disparity looks right of x).
        c0 = max(0, seen[0] - p.blind_band_px - margin)
        c1 = min(width, seen[1] + margin + max(0, -p.min_disparity))
        if (c0, c1) == (0, width) or c1 - c0 <= p.blind_band_px + margin:
            return self._compute(ref, other), 0
        out = np.full(ref.shape, (p.min_disparity - 1) * 16, dtype=np.int16)
        out[:, c0:c1] = self._compute(ref[:, c0:c1], other[:, c0:c1])
        return out, c0

    def _compute_mirrored(self, left: U8, right: U8, seen: tuple[int, int]) -> tuple[NDArray[np.int16], int]:
        """:meth:`_compute_columns` on the mirrored pair, where the right view becomes the
        reference: ``seen`` are the right image's seen columns, mirrored here."""
        width = left.shape[1]
        return self._compute_columns(
            np.asarray(cv2.flip(right, 1), dtype=np.uint8),
            np.asarray(cv2.flip(left, 1), dtype=np.uint8),
            (width - seen[1], width - seen[0]),
        )

    def remove_speckles(self, fixed: NDArray[np.int16]) -> None:
        """OpenCV's speckle removal on a fixed-point disparity (H, W) int16 from :meth:`compute`,
        in place: the pass ``StereoSGBM`` makes at the end of its ``compute`` when
        ``speckle_size`` > 0 (``StereoBM`` makes its own in :meth:`compute`)."""
        p = self.params
        if self._deferred_speckles:
            cv2.filterSpeckles(fixed, (p.min_disparity - 1) * 16, p.speckle_size, 16 * p.speckle_range)

    def raw(self, left: U8, right: U8) -> NDArray[np.int16]:
        """OpenCV's fixed-point disparity (H, W) int16 in 1/16 px: the bare matcher's output."""
        self._check(left, right)
        out = self._compute(left, right)
        self.remove_speckles(out)
        return out

    def disparity_of(self, unfiltered: UnfilteredDisparity) -> MatchedDisparity:
        """Disparity of the left image (H, W) float32 px, NaN where the matcher gave none;
        with ``lr_check`` also NaN where the right image's disparity disagrees. Consumes
        ``unfiltered`` (its arrays are filtered in place)."""
        fixed = unfiltered.left
        self.remove_speckles(fixed)
        disp, valid = self._in_pixels(fixed)
        if unfiltered.mirrored is not None:
            # The half-resolution view had its speckles removed at the resolution it was
            # searched at (rig.half_check); upsampled, it has none of its own.
            right_disp = self._right_from_mirrored(unfiltered.mirrored, speckles=unfiltered.check_scale == 1)
            # Mirrored, the right view's unmatched band (the first min + range columns) is on
            # the right: no evidence there.
            blind = unfiltered.right_unsearched_from
            tolerance = self.params.lr_tolerance(unfiltered.check_scale)
            valid &= left_right_consistent(disp, valid, right_disp, tolerance, blind)
        # OpenCV's masked copy: numpy's boolean assignment branches per pixel (~6 ms on a
        # 1280×960 frame against ~0.3), and this is on every frame's critical path.
        fill_where(disp, np.nan, ~valid)
        return MatchedDisparity(disp, valid)

    def match(self, left: U8, right: U8) -> MatchedDisparity:
        """:meth:`compute` then :meth:`disparity_of`."""
        return self.disparity_of(self.compute(left, right))

    def _in_pixels(self, fixed: NDArray[np.int16]) -> tuple[F32, NDArray[np.bool_]]:
        """A fixed-point disparity (H, W) as float32 px (invalid pixels not yet NaN) and its
        validity: OpenCV marks invalid pixels below ``min_disparity``."""
        valid = fixed >= self.params.min_disparity * 16
        disp = fixed.astype(np.float32)
        disp *= np.float32(1.0 / 16.0)
        return disp, valid

    def _right_from_mirrored(self, mirrored: NDArray[np.int16], *, speckles: bool = True) -> F32:
        if speckles:
            self.remove_speckles(mirrored)
        disp, valid = self._in_pixels(mirrored[:, ::-1])
        fill_where(disp, np.nan, ~valid)
        return disp

    def right_disparity(self, left: U8, right: U8) -> F32:
        """Disparity of the right image (H, W) float32 px (NaN invalid), by matching the
        mirrored pair: in mirrored images the right view becomes the reference."""
        self._check(left, right)
        mirrored, _ = self._compute_mirrored(left, right, (0, left.shape[1]))
        return self._right_from_mirrored(mirrored)
