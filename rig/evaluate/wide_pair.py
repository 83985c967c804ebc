"""The wide-pair study of ``rig evaluate --study wide-pair``: how much of what both lenses see
each rectified pair turns into range, and how accurate that range is, pinhole against lat-lon.

For each pose of the rig in the closed textured room of ``rig sim`` (along its demo path): the
fisheye pair is rendered once (through the preset's honest lens, or the ideal one: ``lens``),
then every variant (a rectified
pair: projection, field and resolution) runs the product's depth pipeline on it; its range
(metres along each left rectified pixel's ray, :func:`rig.depth.disparity_to_range`) is compared
with the renderer's exact range through the same rectified view
(:func:`rig.sim.render.render_range`).

* Coverage: steradians of the overlap (the directions both lenses see, :func:`rig.field.overlap`
  on a fine grid) with valid range, and with range within 1 % and 3 % of the truth: the sum of
  the pixels' solid angles (:func:`rig.field.pixel_solid_angles`), averaged over the poses.
* Error by angle off the forward axis (z of the rectified frame): per 10° bin, the fraction of
  the overlap's solid angle in the bin with range within 3 %, and the median relative error.
* Shared rays: the reference variant's (the default pinhole) pixels whose ray the other variant
  also gives a valid range for (its nearest pixel): both medians over that same set.

Variants by default: the pinhole pair (640×480, 90°); a lat-lon pair with the same pixel budget;
a lat-lon pair with the pinhole's angular resolution at its centre (320 px/rad); a pinhole with
that lat-lon pair's budget and the same centre resolution (992×744, 114°); and lat-lon pairs at
more resolutions for the choice of the default (``resolutions``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from calibration.models import CameraModel
from calibration.rig import Rig
from rig.depth import disparity_to_range
from rig.errors import EvaluationError
from rig.evaluate.renders import lut_box, render_in_box, union_box
from rig.field import overlap, pixel_solid_angles
from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPairConfig, design_rectified_pair, rectified_frame
from rig.sim.lens_effects import check_lens, lens_for
from rig.sim.presets import get_preset
from rig.sim.render import render_range
from rig.sim.scene import Scene, room_scene
from rig.sim.simulate import room_path
from rig.stereo import StereoParams

__all__ = [
    "ANGLE_BINS_DEG",
    "AngleBin",
    "Variant",
    "VariantResult",
    "WideConfig",
    "WideStudy",
    "default_variants",
    "latlon_for_budget",
    "make_wide_config",
    "run_wide_study",
    "study_steps",
]

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

#: Edges of the bins of angle off the forward axis (degrees); the last is open above.
ANGLE_BINS_DEG: tuple[float, ...] = tuple(float(a) for a in range(0, 101, 10))
TOLERANCES = (0.01, 0.03)
REFERENCE_VARIANT = "pinhole"


@dataclass(frozen=True)
class Variant:
    """One rectified pair: a name (a CSV key), its configuration and a label for the figure."""

    name: str
    vpc: RectifiedPairConfig
    label: str


@dataclass(frozen=True)
class WideConfig:
    """One run of the study (see :func:`make_wide_config` for the full and quick values)."""

    preset: str
    scale: float
    poses: tuple[int, ...]  # indices along rig sim's room path of ``path_frames`` frames
    path_frames: int
    supersample: int
    seed: int
    variants: tuple[Variant, ...]
    stereo: StereoParams
    overlap_step_deg: float
    quick: bool
    lens: str = "honest"

    def describe(self) -> dict[str, object]:
        return {
            "preset": self.preset,
            "lens": self.lens,
            "image_scale": self.scale,
            "scene": "room",
            "poses": list(self.poses),
            "path_frames": self.path_frames,
            "supersample": self.supersample,
            "seed": self.seed,
            "overlap_step_deg": self.overlap_step_deg,
            "quick": self.quick,
            "stereo": self.stereo.model_dump(),
            "variants": {v.name: v.vpc.model_dump(exclude_defaults=True) for v in self.variants},
        }


def latlon_for_budget(rig: Rig, pixels: int, blind_band_px: int) -> RectifiedPairConfig:
    """The lat-lon configuration whose default field (the overlap plus the blind band) has about
    ``pixels`` pixels: width ≈ az·f + band, height ≈ el·f, solved for f."""
    R, _ = rectified_frame(rig, "left", "right")
    az_lo, az_hi, el_lo, el_hi = overlap(rig, R, "left", "right").bounds()
    a, e = az_hi - az_lo, el_hi - el_lo
    # (a f + band) · e f = pixels
    f = (-blind_band_px * e + math.sqrt((blind_band_px * e) ** 2 + 4.0 * a * e * pixels)) / (2.0 * a * e)
    return RectifiedPairConfig(projection="latlon", px_per_deg=round(math.radians(f), 3))


def default_variants(
    rig: Rig, stereo: StereoParams, pinhole: RectifiedPairConfig, resolutions: Sequence[float]
) -> tuple[Variant, ...]:
    """The study's variants (see the module doc) for ``rig`` (already scaled) and the pinhole pair
    ``pinhole``; ``resolutions``: more lat-lon px/deg."""
    band = stereo.blind_band_px
    pw, ph, hfov_deg = pinhole.pinhole_size
    f = (pw / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    same_res = RectifiedPairConfig(projection="latlon", px_per_deg=round(math.radians(f), 3))
    wide = design_rectified_pair(rig, same_res, blind_band_px=band).camera
    budget = latlon_for_budget(rig, pw * ph, band)
    # A pinhole of the lat-lon pair's pixel count at the same centre resolution: wider, not finer.
    w = 16 * round(math.sqrt(wide.width * wide.height * pw / ph) / 16)
    h = round(w * ph / pw)
    wide_pinhole = RectifiedPairConfig(
        width=w, height=h, hfov_deg=round(2.0 * math.degrees(math.atan(w / 2.0 / f)), 2)
    )
    out = [
        Variant(
            REFERENCE_VARIANT, pinhole, f"pinhole {pinhole.width}×{pinhole.height}, {pinhole.hfov_deg:g}°"
        ),
        Variant("latlon_budget", budget, f"lat-lon {budget.px_per_deg:g} px/deg (pinhole's pixels)"),
        Variant("latlon", same_res, f"lat-lon {same_res.px_per_deg:g} px/deg (pinhole's centre resolution)"),
        Variant(
            "pinhole_wide", wide_pinhole, f"pinhole {w}×{h}, {wide_pinhole.hfov_deg:g}° (lat-lon's pixels)"
        ),
    ]
    for ppd in resolutions:
        out.append(
            Variant(
                f"latlon_{ppd:g}",
                RectifiedPairConfig(projection="latlon", px_per_deg=ppd),
                f"lat-lon {ppd:g} px/deg",
            )
        )
    return tuple(out)


def make_wide_config(
    preset: str = "prototype",
    *,
    quick: bool = False,
    seed: int = 0,
    lens: str = "honest",
    stereo: StereoParams | None = None,
) -> WideConfig:
    """Full run: the preset's own size, three poses along the room path, supersampling 3×3, the
    default pinhole pair and stereo settings (or ``stereo``), lat-lon resolutions 4.5 and 7
    px/deg besides the budget ones. Quick (tests): a quarter-size rig, one pose, supersampling
    2×2, a 160×120 pinhole and a quarter of the disparities."""
    scale = 0.25 if quick else 1.0
    if stereo is None:
        stereo = StereoParams(disparity_range=32) if quick else StereoParams()
    pinhole = (
        RectifiedPairConfig(width=160, height=120) if quick else RectifiedPairConfig(projection="pinhole")
    )
    rig = get_preset(preset).scaled(scale).rig
    resolutions = () if quick else (4.5, 7.0)
    return WideConfig(
        preset=preset,
        scale=scale,
        poses=(2,) if quick else (0, 2, 4),
        path_frames=5,
        supersample=2 if quick else 3,
        seed=seed,
        variants=default_variants(rig, stereo, pinhole, resolutions),
        stereo=stereo,
        overlap_step_deg=0.5 if quick else 0.1,
        quick=quick,
        lens=check_lens(lens),
    )


@dataclass(frozen=True)
class AngleBin:
    """One bin of angle off the forward axis: the overlap's solid angle in it, the fraction of that
    with valid range and within 3 % (averaged over the poses), the median relative error."""

    lo_deg: float
    hi_deg: float
    overlap_sr: float
    valid_frac: float
    within3_frac: float
    median_error: float


@dataclass(frozen=True)
class VariantResult:
    """One variant over all poses (solid angles are means over the poses)."""

    variant: Variant
    projection: str
    width: int
    height: int
    fx: float
    valid_sr: float
    within_sr: dict[float, float]  # tolerance -> steradians
    median_error: float
    p90_error: float
    bins: list[AngleBin]
    shared: tuple[float, float, float] | None  # (reference median, this median, shared sr)
    process_ms: float  # wall time of DepthPipeline.process per frame (indicative; bench/ measures)

    @property
    def pixels(self) -> int:
        return self.width * self.height


@dataclass
class WideStudy:
    config: WideConfig
    overlap_sr: float
    overlap_bin_sr: list[float]
    results: list[VariantResult]
    timings_s: dict[str, float] = field(default_factory=dict)


@dataclass
class _Measured:
    """Per variant: what the reference comparison needs of each pose, and the running sums."""

    pipeline: DepthPipeline
    solid: F64
    angle: F64  # degrees off the forward axis of every pixel
    errors: list[F32] = field(default_factory=list)  # relative error per pose (NaN invalid)
    ms: list[float] = field(default_factory=list)


def _angles(camera: CameraModel, R_fwd_rect: F64) -> F64:
    """Angle (H, W) in degrees between each pixel's ray and the forward axis (the z of the
    unpitched rectified frame, ``R_fwd_rect`` rotating the view's rays into it)."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    rays, _ = camera.unproject(np.stack([u.ravel(), v.ravel()], 1), in_image=False)
    z = (rays @ R_fwd_rect.T)[:, 2]
    return np.degrees(np.arccos(np.clip(z, -1.0, 1.0))).reshape(camera.height, camera.width)


def _bin_of(angle: F64) -> NDArray[np.intp]:
    edges = np.asarray(ANGLE_BINS_DEG[1:-1])
    return np.searchsorted(edges, angle, side="right")


def study_steps(config: WideConfig) -> int:
    """How many times :func:`run_wide_study` calls its ``step``."""
    return len(config.variants) + len(config.poses) * (1 + len(config.variants))


def run_wide_study(
    config: WideConfig, step: Callable[[str], None] | None = None, cache_dir: str | Path | None = None
) -> WideStudy:
    """Run ``config`` (see the module doc); ``step(description)`` after each unit of work."""
    note = step or (lambda _: None)
    t_start = time.perf_counter()
    rig = get_preset(config.preset).scaled(config.scale).rig
    R_rect, _ = rectified_frame(rig, "left", "right")
    view = overlap(rig, R_rect, "left", "right", config.overlap_step_deg)
    el, az = np.meshgrid(view.el, view.az, indexing="ij")
    grid_angle = np.degrees(np.arccos(np.clip(np.cos(az) * np.cos(el), -1.0, 1.0)))
    cell_sr = np.cos(az) * view.step**2 * view.inside
    n_bins = len(ANGLE_BINS_DEG) - 1
    bin_sr = np.bincount(_bin_of(grid_angle).ravel(), cell_sr.ravel(), n_bins).astype(np.float64)
    measured: dict[str, _Measured] = {}
    for v in config.variants:
        pipe = DepthPipeline(rig, v.vpc, config.stereo, cache_dir, tune_malloc=False)
        R_fwd_rect = R_rect.T @ pipe.pair.R_rig_rect
        measured[v.name] = _Measured(
            pipe, pixel_solid_angles(pipe.pair.camera), _angles(pipe.pair.camera, R_fwd_rect)
        )
        note(f"tables ({v.name})")
    boxes = {
        n: union_box(lut_box(m.pipeline.luts[n], rig.cameras[n]) for m in measured.values())
        for n in ("left", "right")
    }
    scene = room_scene(config.seed)
    effects = lens_for(config.lens, get_preset(config.preset).scaled(config.scale).lens)
    for i, pose in enumerate(config.poses):
        T_world_rig = room_path(pose, config.path_frames)
        seeds = np.random.SeedSequence([config.seed, pose]).generate_state(2)
        images = {
            name: render_in_box(
                scene, rig.cameras[name], T_world_rig @ rig.T_rig_cam[name], boxes[name],
                supersample=config.supersample, seed=int(seeds[k]), lens=effects,
                camera_index=list(rig.cameras).index(name),
            )
            for k, name in enumerate(("left", "right"))
        }  # fmt: skip
        note(f"rendering pose {i + 1} of {len(config.poses)}")
        for v in config.variants:
            _measure(measured[v.name], scene, T_world_rig, images)
            note(f"range and truth ({v.name}, pose {i + 1})")
    results = [_summarise(v, measured, bin_sr, view.solid_angle_sr) for v in config.variants]
    return WideStudy(
        config, view.solid_angle_sr, bin_sr.tolist(), results, {"total": time.perf_counter() - t_start}
    )


def _measure(m: _Measured, scene: Scene, T_world_rig: F64, images: dict[str, NDArray[np.uint8]]) -> None:
    pair = m.pipeline.pair
    t0 = time.perf_counter()
    frame = m.pipeline.process(images["left"], images["right"])
    m.ms.append((time.perf_counter() - t0) * 1e3)
    rng = disparity_to_range(frame.disparity, pair.camera, pair.baseline_m)
    truth, _ = render_range(scene, pair.camera, T_world_rig @ pair.T_rig_rect[pair.left])
    with np.errstate(invalid="ignore", divide="ignore"):
        m.errors.append(np.abs(rng / truth - 1.0).astype(np.float32))  # NaN: no range or no truth


def _summarise(v: Variant, measured: dict[str, _Measured], bin_sr: F64, overlap_sr: float) -> VariantResult:
    m = measured[v.name]
    cam = m.pipeline.pair.camera
    poses = len(m.errors)
    if poses == 0:
        raise EvaluationError("the wide-pair study needs at least one pose")
    bins = _bin_of(m.angle)
    n_bins = len(ANGLE_BINS_DEG) - 1
    valid_sr = 0.0
    within = dict.fromkeys(TOLERANCES, 0.0)
    bin_valid = np.zeros(n_bins)
    bin_within = np.zeros(n_bins)
    for err in m.errors:
        ok = np.isfinite(err)
        valid_sr += float(m.solid[ok].sum()) / poses
        for tol in TOLERANCES:
            within[tol] += float(m.solid[ok & (err < tol)].sum()) / poses
        bin_valid += np.bincount(bins[ok], m.solid[ok], n_bins) / poses
        good = ok & (err < 0.03)
        bin_within += np.bincount(bins[good], m.solid[good], n_bins) / poses
    stacked = np.stack(m.errors)
    all_ok = np.isfinite(stacked)
    pooled = stacked[all_ok]
    angle = np.broadcast_to(m.angle, stacked.shape)[all_ok]
    pooled_bins = _bin_of(angle)
    out_bins = []
    for b in range(n_bins):
        sel = pooled[pooled_bins == b]
        sr = float(bin_sr[b])
        out_bins.append(
            AngleBin(
                ANGLE_BINS_DEG[b],
                ANGLE_BINS_DEG[b + 1],
                sr,
                float(bin_valid[b] / sr) if sr > 0 else math.nan,
                float(bin_within[b] / sr) if sr > 0 else math.nan,
                float(np.median(sel)) if sel.size else math.nan,
            )
        )
    shared = None if v.name == REFERENCE_VARIANT else _shared(measured[REFERENCE_VARIANT], m)
    return VariantResult(
        variant=v,
        projection=m.pipeline.pair.projection,
        width=cam.width,
        height=cam.height,
        fx=cam.fx,
        valid_sr=valid_sr,
        within_sr=within,
        median_error=float(np.median(pooled)) if pooled.size else math.nan,
        p90_error=float(np.percentile(pooled, 90)) if pooled.size else math.nan,
        bins=out_bins,
        shared=shared,
        process_ms=float(np.median(m.ms)),
    )


def _shared(ref: _Measured, other: _Measured) -> tuple[float, float, float]:
    """Medians of the reference's and ``other``'s relative errors over the reference pixels whose
    ray has a valid range in both (``other`` at its nearest pixel), and those pixels' solid angle
    (mean over the poses)."""
    a, b = ref.pipeline.pair, other.pipeline.pair
    cam = a.camera
    v, u = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
    rays, _ = cam.unproject(np.stack([u.ravel(), v.ravel()], 1), in_image=False)
    # Both views sit at the left camera's centre: only their orientations differ.
    px, ok = b.camera.project(rays @ (b.R_rig_rect.T @ a.R_rig_rect).T)
    cols = np.clip(np.rint(px[:, 0]), 0, b.camera.width - 1).astype(np.intp)
    rows = np.clip(np.rint(px[:, 1]), 0, b.camera.height - 1).astype(np.intp)
    mine, theirs, sr = [], [], 0.0
    for e_ref, e_other in zip(ref.errors, other.errors, strict=True):
        there = np.where(ok, e_other[rows, cols], np.nan)
        both = np.isfinite(e_ref.ravel()) & np.isfinite(there)
        mine.append(e_ref.ravel()[both])
        theirs.append(there[both])
        sr += float(ref.solid.ravel()[both].sum()) / len(ref.errors)
    x, y = np.concatenate(mine), np.concatenate(theirs)
    if x.size == 0:
        return (math.nan, math.nan, 0.0)
    return (float(np.median(x)), float(np.median(y)), sr)
