"""Where the real ring's range disagrees with itself and where it has none (docs/ring.md): the
analysis tables of :mod:`bench.ring_consistency`.

* Disagreement of each couple binned by the target's range, by the angle off each of the three
  lenses' axes (A and S of the source pair, B of the target), by elevation in the target's view;
  the distribution of the disparity disagreement; the figures on the pixels the pipeline's own
  confidence trusts.
* Coverage of each pair binned by the angle off the rim-most of its two lenses' axes and by the
  left rectified image's local contrast; and with twice the disparities.
* Renders of the ring's own calibration (its lenses, poses and 0.3 m baselines, the demo room):
  the measure with the exact calibration, then with the calibration the pipeline uses perturbed
  by errors of known kinds and sizes (rotations, translations, distortion centre, focal length).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.geometry import make_transform
from calibration.rig import Rig
from rig.evaluate.consistency import (
    ConsistencyFigures,
    PairRange,
    TransferredRange,
    figures_by,
    range_coverage,
    transfer_range,
    view_mask,
)
from rig.evaluate.consistency_study import ConsistencyStudy, CoupleResult, pair_pipelines, pair_ranges
from rig.field import pixel_solid_angles
from rig.pipeline import DepthPipeline
from rig.rectification import RayMatches
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from rig.ring import PairNames
from rig.stereo import StereoParams

__all__ = [
    "PERTURBATIONS",
    "Bin",
    "ConfidentRanges",
    "CoverageLevel",
    "common_figures",
    "couple_bins",
    "coverage_bins",
    "coverage_with",
    "disparity_shares",
    "matched_coverage",
    "only_points",
    "vertical_by_angle",
]

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

RANGE_EDGES_M = (0.0, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0, 20.0, 1000.0)
ANGLE_EDGES_DEG = (0.0, 30.0, 60.0, 75.0, 90.0, 105.0, 120.0)
ELEVATION_EDGES_DEG = (-120.0, -80.0, -60.0, -40.0, -20.0, 0.0, 20.0, 40.0, 60.0, 80.0, 120.0)
RIM_EDGES_DEG = (0.0, 60.0, 90.0, 100.0, 105.0, 110.0, 115.0)
CONTRAST_EDGES = (0.0, 2.0, 4.0, 8.0, 16.0, 256.0)
DISPARITY_STEPS_PX = (0.5, 1.0, 2.0, 3.0, 5.0)


@dataclass(frozen=True)
class Bin:
    """One row of a binned table: what is binned, the bin and its figures."""

    by: str
    lo: float
    hi: float
    figures: ConsistencyFigures


def _angle_off(pipe: DepthPipeline, name: str, pixels: F64) -> F64:
    """Degrees between camera ``name``'s axis and the rays of ``pipe``'s left view pixels (N, 2)."""
    rays, _ = pipe.pair.camera.unproject(pixels, in_image=False)
    z = (rays @ pipe.pair.R_cam_rect[name].T)[:, 2]
    return np.degrees(np.arccos(np.clip(z, -1.0, 1.0)))


def couple_bins(study: ConsistencyStudy, result: CoupleResult) -> list[Bin]:
    """The couple's points (kept by the study) binned by range, field angles and elevation."""
    t = result.points
    if t is None:
        raise ValueError("the study kept no points: run it with keep_points=True")
    pipes = {p.names: p.pipeline for p in study.pairs}
    src, tgt = pipes[result.couple.source], pipes[result.couple.target]
    width = src.pair.camera.width
    source_px = np.stack([t.source_index % width, t.source_index // width], axis=1).astype(np.float64)
    a, s = result.couple.source
    b = next(n for n in result.couple.target if n != result.couple.shared)
    cam = tgt.pair.camera
    values: list[tuple[str, F64, Sequence[float]]] = [
        ("range from S (m, the target's)", t.r_target, RANGE_EDGES_M),
        (f"angle off A = {a} (deg)", _angle_off(src, a, source_px), ANGLE_EDGES_DEG),
        (f"angle off S = {s} (deg)", _angle_off(tgt, s, t.pixel), ANGLE_EDGES_DEG),
        (f"angle off B = {b} (deg)", _angle_off(tgt, b, t.pixel), ANGLE_EDGES_DEG),
        (
            "elevation in the target's view (deg, down +)",
            np.degrees((t.pixel[:, 1] - cam.cy) / cam.fy),
            ELEVATION_EDGES_DEG,
        ),
    ]
    return [
        Bin(by, lo, hi, f) for by, v, edges in values for lo, hi, f in figures_by(t, v, edges) if f.points
    ]


VERTICAL_EDGES_DEG = (0.0, 70.0, 90.0, 100.0, 115.0)


def vertical_by_angle(
    rig: Rig, names: PairNames, matches: RayMatches
) -> list[tuple[float, float, int, float, float]]:
    """The vertical disparity (px) of ``matches`` (rays of the pair ``names``) in the pair's
    rectified views of ``rig``, binned by the angle off the rim-most of the two lenses' axes:
    rows (lo, hi, matches, median |v_left − v_right|, its signed median)."""
    a, b = names
    pair = design_rectified_pair(rig, RectifiedPairConfig(left=a, right=b))
    pl, ok_l = pair.camera.project(matches.left @ pair.R_cam_rect[a])
    pr, ok_r = pair.camera.project(matches.right @ pair.R_cam_rect[b])
    ok = ok_l & ok_r
    dv = (pl[:, 1] - pr[:, 1])[ok]
    off = np.degrees(np.arccos(np.clip(np.minimum(matches.left[ok, 2], matches.right[ok, 2]), -1.0, 1.0)))
    rows = []
    for lo, hi in itertools.pairwise(VERTICAL_EDGES_DEG):
        m = (off >= lo) & (off < hi)
        if m.any():
            rows.append((lo, hi, int(m.sum()), float(np.median(np.abs(dv[m]))), float(np.median(dv[m]))))
    return rows


def disparity_shares(t: TransferredRange) -> dict[str, float]:
    """Shares of the points both range with |d1 − d2| under each step, and the median of
    d1 − d2 over those within 3 px (the systematic part, the gross mismatches left out)."""
    dd = (t.d_source - t.d_target)[t.both]
    out = {f"within {x:g} px": float(np.mean(np.abs(dd) < x)) for x in DISPARITY_STEPS_PX}
    core = dd[np.abs(dd) < 3.0]
    out["median of those within 3 px (px)"] = float(np.median(core)) if core.size else float("nan")
    return out


@dataclass
class ConfidentRanges:
    """A study's pairs run once more on its frames, keeping each one's range and confidence: the
    pixels above a confidence threshold, their coverage and the study's couples' figures on them."""

    pipelines: dict[PairNames, DepthPipeline]
    #: The study's couples: (source pair, target pair, shared camera).
    couples: list[tuple[PairNames, PairNames, str]]
    #: Per pair, per frame: range (H, W) float32 m (NaN none) and confidence (0 where none).
    outputs: dict[PairNames, list[tuple[NDArray[np.float32], NDArray[np.float32]]]]
    views: dict[PairNames, NDArray[np.bool_]]
    solid: dict[PairNames, F64]

    @classmethod
    def of_study(cls, study: ConsistencyStudy, frames: Sequence[dict[str, U8]]) -> ConfidentRanges:
        pipelines = {p.names: p.pipeline for p in study.pairs}
        outputs = {}
        for p, pipe in pipelines.items():
            outs = [pipe.process(f[p[0]], f[p[1]]) for f in frames]
            outputs[p] = [
                (o.range, o.confidence if o.confidence is not None else np.zeros_like(o.range)) for o in outs
            ]
        views = {
            p: view_mask(pipe.luts[p[0]].valid, pipe.luts[p[1]].valid, pipe.stereo.blind_band_px)
            for p, pipe in pipelines.items()
        }
        return cls(
            pipelines,
            [(c.couple.source, c.couple.target, c.couple.shared) for c in study.couples],
            outputs,
            views,
            {p: pixel_solid_angles(pipe.pair.camera) for p, pipe in pipelines.items()},
        )

    def above(self, pair: PairNames, frame: int, threshold: float) -> PairRange:
        """``pair``'s range on ``frame`` where its confidence exceeds ``threshold`` (NaN elsewhere)."""
        range_m, conf = self.outputs[pair][frame]
        return PairRange(
            self.pipelines[pair].pair,
            np.where(conf > threshold, range_m, np.nan).astype(np.float32),
            self.views[pair],
        )

    def coverage(self, threshold: float) -> float:
        """The pairs' mean coverage (over pairs and frames) of the pixels above ``threshold``."""
        return float(
            np.mean([
                range_coverage(self.above(p, i, threshold), self.solid[p])
                for p, outs in self.outputs.items()
                for i in range(len(outs))
            ])
        )  # fmt: skip

    def threshold_for(self, coverage: float, steps: int = 24) -> float:
        """The lowest confidence threshold whose mean coverage is at most ``coverage`` (−1: every
        pixel, when that is already at most it), by bisection to 2^-``steps``."""
        if self.coverage(-1.0) <= coverage:
            return -1.0
        lo, hi = -1.0, 1.0
        for _ in range(steps):
            mid = (lo + hi) / 2
            lo, hi = (lo, mid) if self.coverage(mid) <= coverage else (mid, hi)
        return hi

    def figures(self, threshold: float) -> dict[str, ConsistencyFigures]:
        """Each couple's figures over the pixels whose confidence (:attr:`rig.pipeline.DepthFrame.
        confidence`) exceeds ``threshold`` in both pairs."""
        per: dict[str, ConsistencyFigures] = {}
        for source, target, shared in self.couples:
            frames = range(len(self.outputs[source]))
            parts = [
                transfer_range(self.above(source, i, threshold), self.above(target, i, threshold), shared)
                for i in frames
            ]
            per[f"{'|'.join(source)} → {'|'.join(target)}"] = ConsistencyFigures.of(
                TransferredRange.concat(parts)
            )
        return per


@dataclass(frozen=True)
class CoverageLevel:
    """One search at a coverage: the confidence ``threshold`` that brings it there, the mean
    ``coverage`` reached and each couple's ``figures`` above the threshold."""

    threshold: float
    coverage: float
    figures: dict[str, ConsistencyFigures]


def matched_coverage(
    searches: Sequence[ConfidentRanges], coverages: Sequence[float]
) -> dict[float, list[CoverageLevel]]:
    """Each search at each of ``coverages``: its most confident pixels (its own threshold) up
    to that mean coverage. Two searches that range different amounts compared where each
    keeps the same share of the overlap, as a precision-recall curve compares two detectors."""
    out: dict[float, list[CoverageLevel]] = {}
    for target in coverages:
        levels = []
        for s in searches:
            thr = s.threshold_for(target)
            levels.append(CoverageLevel(thr, s.coverage(thr), s.figures(thr)))
        out[target] = levels
    return out


def coverage_bins(
    study: ConsistencyStudy, frames: Sequence[dict[str, U8]]
) -> dict[str, list[tuple[str, float, float, float, float]]]:
    """Per pair (label): rows (by, lo, hi, share of the view, coverage) over the frames, binned by
    the angle off the rim-most lens's axis and by local contrast (grey-level std over 9×9 of the
    left rectified image)."""
    out: dict[str, list[tuple[str, float, float, float, float]]] = {}
    for p in study.pairs:
        pipe = p.pipeline
        cam = pipe.pair.camera
        solid = pixel_solid_angles(cam)
        v, u = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
        px = np.stack([u.ravel(), v.ravel()], axis=1)
        rim = np.maximum(*(_angle_off(pipe, n, px) for n in p.names)).reshape(v.shape)
        sums: dict[tuple[str, float, float], list[float]] = {}
        for i, frame in enumerate(frames):
            pr = p.ranges[i]
            left = pipe.luts[p.names[0]].remap(frame[p.names[0]]).astype(np.float32)
            mean = cv2.blur(left, (9, 9))
            contrast = np.sqrt(np.maximum(cv2.blur(left * left, (9, 9)) - mean * mean, 0.0))
            for by, value, edges in (
                ("angle off the rim-most lens (deg)", rim, RIM_EDGES_DEG),
                ("local contrast (grey levels)", contrast, CONTRAST_EDGES),
            ):
                for lo, hi in itertools.pairwise(edges):
                    m = pr.view & (value >= lo) & (value < hi)
                    acc = sums.setdefault((by, lo, hi), [0.0, 0.0, 0.0])
                    acc[0] += float(solid[m].sum())
                    acc[1] += float(solid[m & np.isfinite(pr.range)].sum())
                    acc[2] += float(solid[pr.view].sum())
        out[p.label] = [
            (by, lo, hi, a[0] / a[2], a[1] / a[0] if a[0] else float("nan"))
            for (by, lo, hi), a in sums.items()
        ]
    return out


def coverage_with(
    rig: Rig,
    frames: Sequence[dict[str, U8]],
    pairs: Sequence[PairNames],
    stereo: StereoParams,
    cache_dir: str,
) -> dict[str, float]:
    """Each pair's mean coverage over the frames with other stereo settings."""
    pipes = pair_pipelines(rig, pairs, stereo=stereo, cache_dir=cache_dir)
    out = {}
    for p, pipe in pipes.items():
        solid = pixel_solid_angles(pipe.pair.camera)
        out["|".join(p)] = float(
            np.mean([range_coverage(pair_ranges(pipe, f, i), solid) for i, f in enumerate(frames)])
        )
    return out


# ----- calibration errors of known kinds, for the renders ----------------------------------------


def _each_camera(
    rig: Rig, seed: int, change: Callable[[str, np.random.Generator], tuple[object, F64]]
) -> Rig:
    rng = np.random.default_rng(seed)
    cams, poses = {}, {}
    for n in rig.names:
        cams[n], poses[n] = change(n, rng)
    return Rig(cams, poses)  # type: ignore[arg-type]


def _unit(rng: np.random.Generator, dims: int) -> F64:
    v = rng.normal(size=dims)
    out: F64 = v / np.linalg.norm(v)
    return out


def rotated(rig: Rig, deg: float, seed: int, axis: Sequence[float] | None = None) -> Rig:
    """Every camera turned by ``deg`` about a random axis (or ±``axis`` of its own frame)."""

    def change(n: str, rng: np.random.Generator) -> tuple[object, F64]:
        a = _unit(rng, 3) if axis is None else np.asarray(axis, np.float64) * rng.choice([-1.0, 1.0])
        R = cv2.Rodrigues(a * np.radians(deg))[0]
        return rig.cameras[n], rig.T_rig_cam[n] @ make_transform(R, [0.0, 0.0, 0.0])

    return _each_camera(rig, seed, change)


def translated(rig: Rig, mm: float, seed: int) -> Rig:
    """Every camera moved by ``mm`` in a random direction."""

    def change(n: str, rng: np.random.Generator) -> tuple[object, F64]:
        T = rig.T_rig_cam[n].copy()
        T[:3, 3] += _unit(rng, 3) * mm / 1000.0
        return rig.cameras[n], T

    return _each_camera(rig, seed, change)


def centre_shifted(rig: Rig, px: float, seed: int) -> Rig:
    """Every lens's distortion centre moved by ``px`` in a random direction."""

    def change(n: str, rng: np.random.Generator) -> tuple[object, F64]:
        d, p = _unit(rng, 2) * px, rig.cameras[n].param_dict
        return rig.cameras[n].replace(cx=p["cx"] + d[0], cy=p["cy"] + d[1]), rig.T_rig_cam[n]

    return _each_camera(rig, seed, change)


def focal_scaled(rig: Rig, factor: float, names: Sequence[str]) -> Rig:
    """Cameras ``names`` with their image scale about the centre multiplied by ``factor`` (the
    Scaramuzza polynomial's a_i · factor^(1−i))."""

    def change(n: str, rng: np.random.Generator) -> tuple[object, F64]:
        cam = rig.cameras[n]
        if n not in names:
            return cam, rig.T_rig_cam[n]
        poly = [a * factor ** (1 - i) for i, a in enumerate(cam.param_dict["poly"])]
        return cam.replace(poly=poly), rig.T_rig_cam[n]

    return _each_camera(rig, 0, change)


#: (label, rig -> perturbed rig): the calibration errors the render section tries.
PERTURBATIONS: tuple[tuple[str, Callable[[Rig], Rig]], ...] = (
    ("exact calibration", lambda r: r),
    ("every camera turned 0.1° (random axes)", lambda r: rotated(r, 0.1, 1)),
    ("every camera turned 0.3° (random axes)", lambda r: rotated(r, 0.3, 2)),
    ("every camera turned 0.2° about its vertical (±)", lambda r: rotated(r, 0.2, 1, (0.0, 1.0, 0.0))),
    ("every camera moved 5 mm (random directions)", lambda r: translated(r, 5.0, 1)),
    ("every distortion centre moved 2 px", lambda r: centre_shifted(r, 2.0, 1)),
    ("cam2's image scale +0.5 %", lambda r: focal_scaled(r, 1.005, ("cam2",))),
)


def common_figures(studies: Sequence[ConsistencyStudy]) -> list[dict[str, ConsistencyFigures]]:
    """Each study's couples (the same pairs on the same frames, e.g. two stereo settings, with
    ``keep_ranges``) measured on the pixels where every study has range: one matcher's figures
    against another's on the same points, not each on its own."""
    ranges = [{p.names: p.ranges for p in st.pairs} for st in studies]
    frames = studies[0].frames
    common = {
        names: [
            np.logical_and.reduce([np.isfinite(r[names][i].range) for r in ranges]) for i in range(frames)
        ]
        for names in ranges[0]
    }

    def masked(pr: PairRange, keep: NDArray[np.bool_]) -> PairRange:
        return replace(pr, range=np.where(keep, pr.range, np.float32(np.nan)).astype(np.float32))

    out = []
    for r in ranges:
        figures = {}
        for c in studies[0].couples:
            src, tgt = c.couple.source, c.couple.target
            per = [
                transfer_range(
                    masked(r[src][i], common[src][i]), masked(r[tgt][i], common[tgt][i]), c.couple.shared
                )
                for i in range(frames)
            ]
            figures[c.couple.label] = ConsistencyFigures.of(TransferredRange.concat(per))
        out.append(figures)
    return out


def only_points(
    mine: ConsistencyStudy, other: ConsistencyStudy
) -> dict[str, tuple[TransferredRange, TransferredRange]]:
    """Per couple, ``mine``'s points (both studies on the same frames, with ``keep_ranges``) split
    by their source pixel: (those ``other`` ranges too, those only ``mine`` ranges). The target's
    range is ``mine``'s everywhere: where the points that only one search ranges stand against
    the rest of its own range."""
    theirs = {p.names: p.ranges for p in other.pairs}
    ranges = {p.names: p.ranges for p in mine.pairs}
    out = {}
    for c in mine.couples:
        src, tgt = c.couple.source, c.couple.target
        both, only = [], []
        for i in range(mine.frames):
            t = transfer_range(ranges[src][i], ranges[tgt][i], c.couple.shared)
            also = np.isfinite(theirs[src][i].range).ravel()[t.source_index]
            both.append(t.select(also))
            only.append(t.select(~also))
        out[c.couple.label] = (TransferredRange.concat(both), TransferredRange.concat(only))
    return out
