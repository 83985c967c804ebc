"""A two-camera rig's vergence from a floor at a known height, measured before and after and
applied only when nothing gets worse (docs/rectification.md, "Vergence from the floor").

The frames go through the product's depth pipeline (:class:`rig.pipeline.DepthPipeline`, the
given pair settings, default: today's); the floor's pixels and the right camera's turn about the
rectified y (vergence) and z (the look direction) that put it at ``height_m`` below the rig's
origin, square to the rig's up, are found by :func:`rig.floor.fit_floor`. A turned right camera
changes its rectified view's rows too, which changes what the matcher finds, so the fit is
repeated on the corrected rig's range (``iterations``) and the turns compose.

The result is measured, never trusted: on the same frames, through the pipeline of the rig
before and after, on the same floor rays (the first fit's inliers), the floor's residual against
the known floor (disparity pixels, and its range error), how flat it is (:func:`rig.floor.
fit_plane`: its height, tilt and residual as the range shows it), and the pair's vertical
disparity (:mod:`rig.rectification.measure`, SIFT matches of the frames). The corrected rig is
applied only when none of the floor's residual, its flatness or the vertical disparity gets
worse (each within ``tolerance_px``) and the turn is at most ``max_correction_deg``; otherwise
:attr:`FloorRefinement.applied` is False and :attr:`FloorRefinement.reason` names what did not
hold, mirroring :class:`rig.ring_refine.RingRefinement`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from calibration.rig import Rig
from rig.errors import ConfigError
from rig.floor import (
    FloorFit,
    FloorGeometry,
    FloorOptions,
    FloorSamples,
    fit_floor,
    fit_plane,
    floor_params,
    floor_range,
    floor_residuals,
    floor_samples,
    pixel_samples,
)
from rig.pipeline import DepthFrame, DepthPipeline
from rig.recording import Recording
from rig.rectification.matching import MatchOptions, RayMatches, match_pair
from rig.rectification.measure import VerticalDisparity, vertical_disparity
from rig.rectification.refine import pick_pairs
from rig.rectification.views import EpipolarViews
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from rig.ring import rig_up
from rig.stereo import StereoParams

__all__ = [
    "FloorFigures",
    "FloorRefineOptions",
    "FloorRefinement",
    "recording_frames",
    "refine_floor",
    "turn_camera",
]

U8 = NDArray[np.uint8]
F64 = NDArray[np.float64]
#: ``progress(step, total)`` after each stage of the work.
Progress = Callable[[int, int], None]
#: Heights outside this range (m) are no robot's floor: bad input, not a fit.
HEIGHT_RANGE_M = (0.01, 100.0)


@dataclass(frozen=True)
class FloorRefineOptions:
    """``floor``: how the floor is found and fitted; ``iterations``: fits, each on the range of
    the rig corrected by the ones before; ``max_correction_deg``: a larger turn is not applied
    (recalibrate); ``tolerance_px``: how much worse a figure (disparity pixels) may get and still
    count as no worse; ``view_px_per_deg``/``max_features``: the SIFT matches' epipolar views;
    ``cache_dir``: the lookup tables' cache."""

    floor: FloorOptions = field(default_factory=FloorOptions)
    iterations: int = 2
    max_correction_deg: float = 1.0
    tolerance_px: float = 0.02
    view_px_per_deg: float = 5.0
    max_features: int = 8000
    cache_dir: str | Path | None = None


@dataclass(frozen=True)
class FloorFigures:
    """The floor as one rig's pipeline sees it, on the refinement's floor rays: ``points`` with
    range; ``residual_px`` the median |disparity residual| against the known floor and
    ``range_error`` / ``range_bias`` the median |r / r_floor − 1| and its signed median;
    ``plane``: the plane the range lies on (its ``params[HEIGHT]``, ``tilt_deg`` from up, and
    ``residual_px``: how flat the floor is)."""

    points: int
    residual_px: float
    range_error: float
    range_bias: float
    plane: FloorFit

    @property
    def height_m(self) -> float:
        return float(self.plane.params[4])

    @property
    def flatness_px(self) -> float:
        return self.plane.residual_px


@dataclass(frozen=True)
class FloorRefinement:
    """What :func:`refine_floor` did: the rig before and after (``rig`` is the one to use: the
    corrected one only when ``applied``), the right camera's turn about the rectified y
    (vergence) and z (the look direction) in degrees with its 1σ and their correlation (of the
    last fit), the floor and the vertical disparity before and after."""

    rig_before: Rig
    rig_after: Rig
    applied: bool
    reason: str | None
    height_m: float
    up: F64
    correction_deg: F64
    sigma_deg: F64
    correlation: float
    fit: FloorFit
    floor_before: FloorFigures
    floor_after: FloorFigures
    vertical_before: VerticalDisparity
    vertical_after: VerticalDisparity
    frames: int

    @property
    def rig(self) -> Rig:
        return self.rig_after if self.applied else self.rig_before

    @property
    def angle_deg(self) -> float:
        return float(np.hypot(*self.correction_deg))

    def summary(self) -> list[str]:
        """The figures in lines of text: the turn, the floor and the vertical disparity before
        and after, and whether it was applied."""
        fb, fa = self.floor_before, self.floor_after
        y, z = self.correction_deg
        sy, sz = self.sigma_deg
        vb, va = self.vertical_before, self.vertical_after
        return [
            f"right camera turned {y:+.4f}° about y (vergence, 1σ {sy:.4f}°), {z:+.4f}° about z (the look "
            f"direction, 1σ {sz:.4f}°; correlation {self.correlation:+.2f}), from {self.fit.cells} cells of "
            f"floor in {self.frames} frame(s), floor {self.height_m:.3f} m down",
            f"floor residual {fb.residual_px:.3f} -> {fa.residual_px:.3f} px; range error "
            f"{fb.range_error:.2%} -> {fa.range_error:.2%} (bias {fb.range_bias:+.2%} -> "
            f"{fa.range_bias:+.2%})",
            f"floor as the range shows it: {fb.height_m:.3f} -> {fa.height_m:.3f} m down, tilt "
            f"{_deg(fb.plane.tilt_deg)} -> {_deg(fa.plane.tilt_deg)}, flatness {fb.flatness_px:.3f} -> "
            f"{fa.flatness_px:.3f} px",
            f"vertical disparity p50 {_px(vb.p50_px)} -> {_px(va.p50_px)} px ({vb.count} matches)",
            "applied" if self.applied else str(self.reason),
        ]


def turn_camera(rig: Rig, name: str, rotvec: ArrayLike) -> Rig:
    """``rig`` with camera ``name`` turned by ``rotvec`` (radians, rig frame) about its centre."""
    T = {n: t.copy() for n, t in rig.T_rig_cam.items()}
    T[name][:3, :3] = Rotation.from_rotvec(np.asarray(rotvec, dtype=np.float64)).as_matrix() @ T[name][:3, :3]
    return Rig(dict(rig.cameras), T)


def recording_frames(
    recording: Recording, frames: int, config: RectifiedPairConfig | None = None
) -> list[tuple[U8, U8]]:
    """Up to ``frames`` grey pairs evenly spread over ``recording`` (RecordingError: it lacks a
    camera of ``config``'s pair, holds no pairs, or a frame cannot be read)."""
    config = config or RectifiedPairConfig()
    return [
        (
            recording.read_image(p, "left", cv2.IMREAD_GRAYSCALE),
            recording.read_image(p, "right", cv2.IMREAD_GRAYSCALE),
        )
        for p in pick_pairs(recording, frames, config.left, config.right)
    ]


def _check_height(height_m: float) -> float:
    h = float(height_m)
    lo, hi = HEIGHT_RANGE_M
    if not (math.isfinite(h) and lo <= h <= hi):
        raise ConfigError(f"floor height must be a number of metres in [{lo:g}, {hi:g}], got {height_m!r}")
    return h


class _Run:
    """One rig's pipeline over the frames."""

    def __init__(
        self, rig: Rig, frames: Sequence[tuple[U8, U8]], config: RectifiedPairConfig,
        stereo: StereoParams | None, cache: str | Path | None,
    ) -> None:  # fmt: skip
        self.rig = rig
        self.pipeline = DepthPipeline(rig, config, stereo, cache, tune_malloc=False)
        self.outputs: list[DepthFrame] = [
            self.pipeline.process(a, b, seq=i) for i, (a, b) in enumerate(frames)
        ]

    def geometry(self, up: F64) -> FloorGeometry:
        return FloorGeometry.of(self.pipeline.pair, up)

    def candidates(self, geo: FloorGeometry, height_m: float, opts: FloorOptions) -> FloorSamples:
        pair = self.pipeline.pair
        return FloorSamples.concat(
            [
                floor_samples(pair, o.range, o.disparity, geo, height_m, opts, i)
                for i, o in enumerate(self.outputs)
            ]
        )

    def at_rays(self, rays: F64, frame: NDArray[np.intp], cell_px: int) -> FloorSamples:
        """The samples of the left view's pixels nearest to ``rays`` (rig frame) of each frame."""
        pair = self.pipeline.pair
        px, ok = pair.camera.project(rays @ pair.R_rig_rect)
        cols, rows = (np.rint(px[:, k]).astype(np.intp) for k in (0, 1))
        parts = [
            pixel_samples(
                pair, o.range, o.disparity, rows[ok & (frame == i)], cols[ok & (frame == i)], i, cell_px
            )
            for i, o in enumerate(self.outputs)
        ]
        return FloorSamples.concat(parts)


def _figures(run: _Run, up: F64, height_m: float, floor: FloorSamples, opts: FloorOptions) -> FloorFigures:
    geo = run.geometry(up)
    s = run.at_rays(floor.a, floor.frame, opts.cell_px)
    known = floor_params(height_m)
    ratio = s.range / floor_range(geo, s, known) - 1.0
    return FloorFigures(
        len(s),
        float(np.median(np.abs(floor_residuals(geo, s, known)))) * geo.fx,
        float(np.nanmedian(np.abs(ratio))),
        float(np.nanmedian(ratio)),
        fit_plane(geo, s, height_m, opts),
    )


def _vertical(
    before: Rig,
    after: Rig,
    frames: Sequence[tuple[U8, U8]],
    config: RectifiedPairConfig,
    opts: FloorRefineOptions,
) -> tuple[VerticalDisparity, VerticalDisparity]:
    """The vertical disparity of the frames' SIFT matches in the pair of ``before`` and of
    ``after`` (the matches are rays in each camera's own frame: the same for both)."""
    views = EpipolarViews(
        before, config.left, config.right, max_px_per_deg=opts.view_px_per_deg, cache_dir=opts.cache_dir
    )
    match = MatchOptions(max_features=opts.max_features)
    m = RayMatches.concat([match_pair(views, a, b, match, frame=i) for i, (a, b) in enumerate(frames)])
    return tuple(  # type: ignore[return-value]
        vertical_disparity(design_rectified_pair(r, config), m.left, m.right) for r in (before, after)
    )


def _worse(before: float | None, after: float | None, tolerance: float) -> bool:
    return before is not None and (after is None or after > before + tolerance)


def _verdict(
    angle_deg: float, fb: FloorFigures, fa: FloorFigures, vb: VerticalDisparity, va: VerticalDisparity,
    opts: FloorRefineOptions,
) -> str | None:  # fmt: skip
    """Why the correction is not applied (None: it is)."""
    tol = opts.tolerance_px
    worse = []
    if angle_deg > opts.max_correction_deg:
        worse.append(f"the turn {angle_deg:.3f}° is over {opts.max_correction_deg:g}° (recalibrate)")
    if _worse(fb.residual_px, fa.residual_px, tol):
        worse.append(f"the floor's residual {fb.residual_px:.3f} -> {fa.residual_px:.3f} px")
    if _worse(fb.flatness_px, fa.flatness_px, tol):
        worse.append(f"the floor's flatness {fb.flatness_px:.3f} -> {fa.flatness_px:.3f} px")
    if _worse(vb.p50_px, va.p50_px, tol):
        worse.append(f"the vertical disparity p50 {vb.p50_px:.3f} -> {_px(va.p50_px)} px")
    return None if not worse else "not applied: " + "; ".join(worse)


def _px(v: float | None) -> str:
    return "none" if v is None else f"{v:.3f}"


def _deg(tilt: F64) -> str:
    return f"({tilt[0]:+.3f}, {tilt[1]:+.3f})°"


def refine_floor(
    rig: Rig,
    frames: Sequence[tuple[U8, U8]],
    height_m: float,
    *,
    up: ArrayLike | None = None,
    config: RectifiedPairConfig | None = None,
    stereo: StereoParams | None = None,
    options: FloorRefineOptions | None = None,
    progress: Progress | None = None,
) -> FloorRefinement:
    """Correct the right camera of ``config``'s pair (default today's left|right) so that the
    floor ``height_m`` below the rig's origin, square to ``up`` (default
    :func:`rig.ring.rig_up`), is where its range says, from ``frames`` (gray fisheye pairs), and
    measure it (see the module doc). ConfigError for a height out of range; RectificationError
    when there is no floor in view."""
    h = _check_height(height_m)
    config = config or RectifiedPairConfig()
    opts = options or FloorRefineOptions()
    n_up = rig_up(rig) if up is None else np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    total = opts.iterations + 2

    def step(k: int) -> None:
        if progress is not None:
            progress(k, total)

    first = run = _Run(rig, frames, config, stereo, opts.cache_dir)
    fits: list[FloorFit] = []
    floor: FloorSamples | None = None
    for k in range(opts.iterations):
        geo = run.geometry(n_up)
        candidates = run.candidates(geo, h, opts.floor)
        fits.append(fit_floor(geo, candidates, h, opts.floor))
        floor = floor or candidates.select(fits[0].inliers)
        turned = turn_camera(run.rig, config.right, geo.omega(fits[-1].params))
        run = _Run(turned, frames, config, stereo, opts.cache_dir)
        step(k + 1)
    assert floor is not None  # iterations >= 1
    fb, fa = (_figures(r, n_up, h, floor, opts.floor) for r in (first, run))
    vb, va = _vertical(rig, run.rig, frames, config, opts)
    step(total)
    turn = Rotation.from_matrix(
        run.rig.T_rig_cam[config.right][:3, :3] @ rig.T_rig_cam[config.right][:3, :3].T
    )
    geo0 = first.geometry(n_up)
    correction = np.degrees([turn.as_rotvec() @ geo0.y, turn.as_rotvec() @ geo0.z])
    reason = _verdict(float(np.hypot(*correction)), fb, fa, vb, va, opts)
    return FloorRefinement(
        rig_before=rig,
        rig_after=run.rig,
        applied=reason is None,
        reason=reason,
        height_m=h,
        up=n_up,
        correction_deg=correction,
        sigma_deg=fits[-1].omega_sigma_deg,
        correlation=fits[-1].correlation,
        fit=fits[0],
        floor_before=fb,
        floor_after=fa,
        vertical_before=vb,
        vertical_after=va,
        frames=len(frames),
    )
