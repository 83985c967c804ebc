"""One evaluation run end to end: calibration study → image comparison → plane renders through
every pipeline and matcher → averaged curves. Writing the outputs is :mod:`rig.evaluate.report`.

Renders are made once per (distance, texture) and fed to every pipeline and matcher; lookup
tables go to a temporary cache directory of the run (or ``cache_dir``).
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from calibration.rig import Rig
from rig.errors import EvaluationError
from rig.evaluate.calibration_quality import CalibrationStudy, distinct_lenses, run_calibration_study
from rig.evaluate.config import EvalConfig
from rig.evaluate.depth_quality import (
    REFERENCE,
    TRUE_LENS,
    CurvePoint,
    DepthSample,
    average_curves,
    build_pipelines,
    measure_depth,
    reference_rig,
    theory_curve,
)
from rig.evaluate.distortion import DistortionStudy, run_distortion_study
from rig.evaluate.extrinsics import ExtrinsicsStudy, run_extrinsics_study
from rig.evaluate.extrinsics import steps as extrinsics_steps
from rig.evaluate.matchers import (
    MatcherPoint,
    MatcherSample,
    average_matchers,
    build_matchers,
    measure_matchers,
)
from rig.evaluate.provenance import SourceRevision, source_revision
from rig.evaluate.renders import Box, lut_box, render_plane_shot, union_box
from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPair, design_rectified_pair
from rig.sim.presets import Preset, get_preset

__all__ = ["EvaluationRun", "ProgressSink", "run_evaluation"]


class ProgressSink(Protocol):
    """Receives the number of steps once, then one call per finished step."""

    def start(self, total: int) -> None: ...

    def step(self, description: str) -> None: ...


class _Silent:
    def start(self, total: int) -> None:
        pass

    def step(self, description: str) -> None:
        pass


@dataclass
class EvaluationRun:
    """Everything measured in one run (the report turns it into files)."""

    config: EvalConfig
    preset: Preset  # scaled as the run used it
    pair: RectifiedPair
    calibration: CalibrationStudy
    distortion: DistortionStudy
    depth: dict[str, list[CurvePoint]]  # reference, true_lens, models, theory
    depth_fits: dict[str, tuple[float, float, float] | None]
    depth_errors: dict[str, str]  # curves that could not be measured, with the reason
    theory_sigma_d_px: float
    matchers: dict[str, tuple[list[MatcherPoint], float]]
    extrinsics: ExtrinsicsStudy | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    source: SourceRevision | None = None  # the code that ran (None: not a git checkout)


def run_evaluation(
    config: EvalConfig, progress: ProgressSink | None = None, cache_dir: str | Path | None = None
) -> EvaluationRun:
    """Run every part of the evaluation of ``config`` (see the package doc)."""
    sink = progress or _Silent()
    source = source_revision()  # before the run: the code it starts with
    preset = get_preset(config.preset).scaled(config.scale)
    rig = preset.rig
    pair = design_rectified_pair(rig, config.vpc)
    n_lenses = len(set(distinct_lenses(rig).values()))
    n_scenes = len(config.distances) * len(config.textures)
    sink.start(
        n_lenses * (config.calibration_views + len(config.models))
        + 2
        + 2 * n_scenes
        + extrinsics_steps(config)
    )
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    study = run_calibration_study(rig, config, config.models, sink.step, config.lens_effects(preset))
    timings["calibration"] = time.perf_counter() - t0
    ok_models = [m for m in config.models if study.models[m].ok]

    rigs: dict[str, Rig] = {REFERENCE: reference_rig(pair), TRUE_LENS: rig}
    rigs |= {m: study.calibrated_rig(rig, m) for m in ok_models}

    t0 = time.perf_counter()
    extrinsics = run_extrinsics_study(preset, study, config, sink.step)
    timings["extrinsics"] = time.perf_counter() - t0
    rigs |= extrinsics.rigs or {}

    t0 = time.perf_counter()
    left_models = {TRUE_LENS: rig.cameras[pair.left]} | {m: rigs[m].cameras[pair.left] for m in ok_models}
    distortion = run_distortion_study(
        rig, pair, left_models, seed=config.seed, supersample=config.supersample, step=sink.step
    )
    timings["image_difference"] = time.perf_counter() - t0

    with tempfile.TemporaryDirectory(prefix="rig-evaluate-lut-") as tmp:
        cache = Path(cache_dir) if cache_dir is not None else Path(tmp)
        t0 = time.perf_counter()
        pipelines, errors = build_pipelines(rigs, config.vpc, config.stereo, cache)
        if REFERENCE not in pipelines:
            raise EvaluationError(f"the Reference pipeline cannot be built: {errors.get(REFERENCE)}")
        matchers = build_matchers(rigs[REFERENCE], config.vpc, config.stereo, cache)
        timings["lookup_tables"] = time.perf_counter() - t0
        boxes = _fisheye_boxes(rig, pair, pipelines)
        samples: list[DepthSample] = []
        matcher_samples: list[MatcherSample] = []
        render_s = depth_s = match_s = 0.0
        phase_rng = np.random.default_rng([config.seed, 23])
        for k in config.distances:
            # Stratified sub-pixel disparity phases in [-0.5, 0.5), one stratum per texture.
            n = len(config.textures)
            phases = (np.arange(n) + phase_rng.random()) / n - 0.5
            for texture, phase in zip(config.textures, phases, strict=True):
                t0 = time.perf_counter()
                shot = render_plane_shot(
                    rig, pair, k, texture, boxes, phase_px=float(phase), seed=config.seed,
                    supersample=config.plane_supersample, noise_std=0.0, vignetting=0.0,
                    lens=config.lens_effects(preset),
                )  # fmt: skip
                render_s += time.perf_counter() - t0
                sink.step(f"rendering planes (k = {k:g}, {texture})")
                t0 = time.perf_counter()
                samples += measure_depth(
                    pipelines, shot, pair, seed=config.seed, vicinity_frac=config.vicinity_frac,
                    samples=config.samples,
                )  # fmt: skip
                t1 = time.perf_counter()
                matcher_samples += measure_matchers(matchers, shot, pair)
                depth_s += t1 - t0
                match_s += time.perf_counter() - t1
                sink.step(f"depth and matchers (k = {k:g}, {texture})")
        timings |= {"plane_renders": render_s, "depth_pipelines": depth_s, "matchers": match_s}

    curves, fits = average_curves(samples)
    theory, sigma_d = theory_curve(curves[REFERENCE], pair)
    curves["theory"] = theory
    fits["theory"] = None
    return EvaluationRun(
        config=config,
        preset=preset,
        pair=pair,
        calibration=study,
        distortion=distortion,
        depth=curves,
        depth_fits=fits,
        depth_errors=errors,
        theory_sigma_d_px=sigma_d,
        matchers=average_matchers(matcher_samples),
        extrinsics=extrinsics,
        timings_s=timings,
        source=source,
    )


def _fisheye_boxes(rig: Rig, pair: RectifiedPair, pipelines: dict[str, DepthPipeline]) -> dict[str, Box]:
    """Per fisheye camera: the region every fisheye pipeline's table reads (their union)."""
    boxes: dict[str, Box] = {}
    for name in (pair.left, pair.right):
        parts = [
            lut_box(p.luts[name], rig.cameras[name]) for curve, p in pipelines.items() if curve != REFERENCE
        ]
        boxes[name] = union_box(parts)
    return boxes
