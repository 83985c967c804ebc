"""Matcher choice: OpenCV's SGBM (5 paths), SGBM_3WAY and BM, and our default stage chain
(SGBM_3WAY + Lucas-Kanade subpixel refinement + median + confidence), on the Reference pairs of
the plane scenes (no lookup table in the way: the matchers alone).

The three OpenCV matchers run with the product's window, disparity range, uniqueness and
speckle settings (those are matcher parameters in OpenCV) and none of our stages. Per distance:
disparity error against the exact disparity ``fx·B/z``, valid fraction; per matcher: the
median time per frame of the stereo stages (everything but the identity remap), measured in
this run on this machine — informational, it depends on the load.
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.rig import Rig
from rig.evaluate.metrics import DisparityStats, disparity_stats, finite_mean
from rig.evaluate.renders import PlaneShot
from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPair, RectifiedPairConfig
from rig.stereo import StereoParams

__all__ = [
    "MATCHER_LABELS",
    "MatcherPoint",
    "MatcherSample",
    "average_matchers",
    "build_matchers",
    "measure_matchers",
]

#: Key in results.json -> label in tables and plots.
MATCHER_LABELS: dict[str, str] = {
    "sgbm": "SGBM",
    "sgbm_3way": "SGBM_3WAY",
    "bm": "BM",
    "ours": "ours (SGBM_3WAY + subpixel + filters)",
}


def matcher_params(base: StereoParams) -> dict[str, StereoParams]:
    """The compared settings, all with ``base``'s window and disparity range."""
    plain = {"subpixel": False, "median": 0, "confidence": False}
    return {
        "sgbm": base.model_copy(update={"sgbm_mode": "sgbm", **plain}),
        "sgbm_3way": base.model_copy(update={"sgbm_mode": "3way", **plain}),
        "bm": base.model_copy(update={"stereo_algorithm": 0, **plain}),
        "ours": base,
    }


def build_matchers(
    ref_rig: Rig, vpc: RectifiedPairConfig, base: StereoParams, cache_dir: Path
) -> dict[str, DepthPipeline]:
    # Validate through the model: model_copy(update=...) does not run the validators.
    params = {k: StereoParams.model_validate(p.model_dump()) for k, p in matcher_params(base).items()}
    return {name: DepthPipeline(ref_rig, vpc, p, cache_dir) for name, p in params.items()}


@dataclass(frozen=True)
class MatcherSample:
    matcher: str
    k: float
    texture: str
    stats: DisparityStats
    time_ms: float


def measure_matchers(
    pipelines: Mapping[str, DepthPipeline], shot: PlaneShot, pair: RectifiedPair
) -> list[MatcherSample]:
    """Every matcher on the Reference pair of ``shot``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        truth = (pair.fx * pair.baseline_m / shot.depth_true).astype(np.float32)
    out = []
    for name, pipe in pipelines.items():
        frame = pipe.process(shot.ref_left, shot.ref_right)
        t = frame.timings_ms["total"] - frame.timings_ms["remap"]
        out.append(MatcherSample(name, shot.k, shot.texture, disparity_stats(frame.disparity, truth), t))
    return out


@dataclass(frozen=True)
class MatcherPoint:
    """One matcher at one distance, averaged over the textures."""

    k: float
    rms_px: float
    rms_inlier_px: float
    bad1_frac: float
    valid_frac: float


def average_matchers(samples: Sequence[MatcherSample]) -> dict[str, tuple[list[MatcherPoint], float]]:
    """Per matcher: its points over k and its median time per frame (ms)."""
    out: dict[str, tuple[list[MatcherPoint], float]] = {}
    for name in dict.fromkeys(s.matcher for s in samples):
        mine = [s for s in samples if s.matcher == name]
        points = []
        for k in sorted({s.k for s in mine}):
            at = [s.stats for s in mine if s.k == k]
            points.append(
                MatcherPoint(
                    k,
                    finite_mean([a.rms_px for a in at]),
                    finite_mean([a.rms_inlier_px for a in at]),
                    finite_mean([a.bad1_frac for a in at]),
                    finite_mean([a.valid_frac for a in at]),
                )
            )
        out[name] = (points, float(statistics.median(s.time_ms for s in mine)))
    return out
