"""Depth quality (the paper's Fig. 7 and 12): the textured plane at k baselines through the full
depth pipeline of each calibrated model, the Reference pair, and the theoretical curve.

* Each model: the fisheye pair (rendered through the true lens) → :class:`rig.pipeline.DepthPipeline`
  built with that model's calibration of each camera and the true extrinsics → depth.
* ``true_lens``: the same with the exact lens (the paper's "ideal model embedded in the virtual
  camera"): the loss of resampling the fisheye image alone.
* ``reference``: ideal pinhole cameras at the VPC poses, rendered directly, through the same
  pipeline code: a rig of two such pinholes gives the same VPC pair with identity tables, so the
  matcher, refinement and filters are the very same stages and settings.
* ``theory``: ``σZ = Z²·σd/(fx·B)`` with σd the Reference's measured disparity RMS (median over
  the distances): the curve an ideal stereo pair with that matching precision would follow.

Per (curve, k) the per-texture numbers of :func:`rig.evaluate.metrics.plane_depth_stats` are
averaged (arithmetic mean) over the textures, then a 2nd-order polynomial is fitted over k.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from calibration.models import PinholeModel
from calibration.rig import Rig
from rig.errors import EvaluationError, RigError
from rig.evaluate.metrics import (
    PlaneStats,
    finite_mean,
    fit_quadratic,
    plane_depth_stats,
    plane_in_frame,
    theory_sigma_z,
)
from rig.evaluate.renders import PlaneShot
from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPair, RectifiedPairConfig
from rig.stereo import StereoParams

__all__ = [
    "REFERENCE",
    "THEORY",
    "TRUE_LENS",
    "CurvePoint",
    "DepthSample",
    "average_curves",
    "build_pipelines",
    "measure_depth",
    "reference_rig",
    "theory_curve",
]

REFERENCE = "reference"
TRUE_LENS = "true_lens"
THEORY = "theory"


def reference_rig(pair: RectifiedPair) -> Rig:
    """Two ideal pinholes exactly at the VPC poses (the paper's Reference cameras): designing a
    VPC pair on this rig gives the same pair with R_cam_rect = I (identity lookup tables)."""
    return Rig(
        {pair.left: pair.camera, pair.right: pair.camera.replace()},
        {pair.left: pair.T_rig_rect[pair.left].copy(), pair.right: pair.T_rig_rect[pair.right].copy()},
    )


def build_pipelines(
    rigs: Mapping[str, Rig], vpc: RectifiedPairConfig, stereo: StereoParams, cache_dir: Path
) -> tuple[dict[str, DepthPipeline], dict[str, str]]:
    """One pipeline per curve name; curves whose pipeline cannot be built (e.g. a model whose
    field ends before the VPC's) go into the second dict with the reason."""
    pipes: dict[str, DepthPipeline] = {}
    errors: dict[str, str] = {}
    for name, rig in rigs.items():
        try:
            pipes[name] = DepthPipeline(rig, vpc, stereo, cache_dir)
        except RigError as err:
            errors[name] = str(err)
    return pipes, errors


@dataclass(frozen=True)
class DepthSample:
    """One curve on one rendered plane."""

    curve: str
    k: float
    texture: str
    stats: PlaneStats


def measure_depth(
    pipelines: Mapping[str, DepthPipeline],
    shot: PlaneShot,
    pair: RectifiedPair,
    *,
    seed: int,
    vicinity_frac: float,
    samples: int,
) -> list[DepthSample]:
    """Depth of ``shot`` through every pipeline (the Reference one takes the Reference pair)."""
    if not isinstance(pair.camera, PinholeModel):
        raise EvaluationError(
            "the paper's depth evaluation is of the pinhole pair (RectifiedPairConfig projection pinhole)"
        )
    # The plane z = D of the rig frame, in the left VPC frame.
    plane = plane_in_frame(pair.T_rig_rect[pair.left], [0.0, 0.0, 1.0], shot.distance_m)
    out = []
    for i, (name, pipe) in enumerate(pipelines.items()):
        left, right = (shot.ref_left, shot.ref_right) if name == REFERENCE else (shot.left, shot.right)
        frame = pipe.process(left, right)
        rng = np.random.default_rng([seed, round(shot.k * 1000), sum(map(ord, shot.texture)), i])
        stats = plane_depth_stats(
            frame.depth, shot.depth_true, pair.camera, plane, rng,
            baseline_m=pair.baseline_m, vicinity_frac=vicinity_frac, samples=samples,
        )  # fmt: skip
        out.append(DepthSample(name, shot.k, shot.texture, stats))
    return out


@dataclass(frozen=True)
class CurvePoint:
    """One point of a depth curve, averaged over the textures (``n`` of them had points near
    the plane): RMS, standard deviation and mean (the bias: estimated − true) of the depth error;
    ``fit_rms_m`` is the fitted polynomial at k (None without a fit)."""

    k: float
    rms_m: float
    std_m: float
    mean_m: float
    valid_frac: float
    disparity_rms_px: float
    n: int
    fit_rms_m: float | None = None


def average_curves(
    samples: Sequence[DepthSample],
) -> tuple[dict[str, list[CurvePoint]], dict[str, tuple[float, float, float] | None]]:
    """Per curve: points over k (texture means) with their fitted values, and the fit
    (a2, a1, a0) of RMS against k (None with fewer than 3 distances)."""
    curves: dict[str, list[CurvePoint]] = {}
    fits: dict[str, tuple[float, float, float] | None] = {}
    for name in dict.fromkeys(s.curve for s in samples):
        mine = [s for s in samples if s.curve == name]
        points = []
        for k in sorted({s.k for s in mine}):
            at = [s.stats for s in mine if s.k == k]
            points.append(
                CurvePoint(
                    k=k,
                    rms_m=finite_mean([a.rms_m for a in at]),
                    std_m=finite_mean([a.std_m for a in at]),
                    mean_m=finite_mean([a.mean_m for a in at]),
                    valid_frac=finite_mean([a.valid_frac for a in at]),
                    disparity_rms_px=finite_mean([a.disparity_rms_px for a in at]),
                    n=sum(math.isfinite(a.rms_m) for a in at),
                )
            )
        fit = fit_quadratic([p.k for p in points], [p.rms_m for p in points])
        fits[name] = fit
        if fit is not None:
            a2, a1, a0 = fit
            points = [replace(p, fit_rms_m=a2 * p.k**2 + a1 * p.k + a0) for p in points]
        curves[name] = points
    return curves, fits


def theory_curve(reference: Sequence[CurvePoint], pair: RectifiedPair) -> tuple[list[CurvePoint], float]:
    """The theoretical σZ at the Reference's distances, and the σd (px) it uses: the median of
    the Reference's disparity RMS over the distances (NaN curve when there is none)."""
    measured = [p.disparity_rms_px for p in reference if math.isfinite(p.disparity_rms_px)]
    sigma_d = statistics.median(measured) if measured else math.nan
    B = pair.baseline_m
    out = []
    for p in reference:
        s = float(theory_sigma_z(p.k * B, sigma_d, pair.fx, B))
        out.append(CurvePoint(p.k, s, s, 0.0, math.nan, sigma_d, 0, s))
    return out, sigma_d
