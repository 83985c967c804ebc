"""The consistency study of a rig of N cameras: every stereo pair through the depth pipeline on
the same frames, then every couple of pairs sharing a camera compared (docs/ring.md;
:mod:`rig.evaluate.consistency` defines the measure). The library entry point of ``rig evaluate
--study consistency``: :func:`consistency_study` takes the frames in memory, one image per
camera each.

Each pair is today's whole pipeline (:class:`rig.pipeline.DepthPipeline` with the pair's cameras
as ``left``/``right``, lookup tables from the cache), on the rig's calibration or on its own
(``rigs``: e.g. each pair refined by ``rig calibrate refine`` on its own, which moves its right
camera and nothing else). Figures are per couple pooled over the frames, and per frame.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from calibration.rig import Rig
from rig.errors import EvaluationError
from rig.evaluate.consistency import (
    ConsistencyFigures,
    Couple,
    PairRange,
    TransferredRange,
    couples,
    range_coverage,
    transfer_range,
    view_mask,
)
from rig.field import pixel_solid_angles
from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPairConfig
from rig.rig_pipeline import pair_config
from rig.ring import PairNames, adjacent_pairs, stereo_pairs
from rig.stereo import StereoParams

__all__ = [
    "ConsistencyStudy",
    "CoupleResult",
    "PairResult",
    "consistency_study",
    "pair_pipelines",
    "pair_ranges",
]

U8 = NDArray[np.uint8]
F64 = NDArray[np.float64]
#: One frame: an image (gray or BGR uint8) per camera name.
Frame = Mapping[str, U8]
#: ``progress(done, total)`` after each pair of each frame.
Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class PairResult:
    """One pair over the frames: its pipeline, the coverage of each frame and, with
    ``keep_ranges``, each frame's :class:`PairRange`."""

    names: PairNames
    pipeline: DepthPipeline
    coverage: list[float]
    ranges: list[PairRange] = field(default_factory=list)

    @property
    def label(self) -> str:
        return "|".join(self.names)

    @property
    def mean_coverage(self) -> float:
        return float(np.mean(self.coverage))


@dataclass(frozen=True)
class CoupleResult:
    """One couple: the figures of every frame's points pooled, each frame's, and (with
    ``keep_points``) the pooled points themselves, with ``frame`` (N,) the frame of each."""

    couple: Couple
    figures: ConsistencyFigures
    per_frame: list[ConsistencyFigures]
    points: TransferredRange | None = None
    frame: NDArray[np.intp] | None = None


@dataclass(frozen=True)
class ConsistencyStudy:
    """Every pair and every couple of pairs sharing a camera (see the module doc)."""

    pairs: list[PairResult]
    couples: list[CoupleResult]
    frames: int

    def as_dict(self) -> dict[str, object]:
        """The figures as plain data (a JSON report)."""
        return {
            "frames": self.frames,
            "pairs": {
                p.label: {"coverage": p.coverage, "mean_coverage": p.mean_coverage} for p in self.pairs
            },
            "couples": {
                c.couple.label: {
                    "shared": c.couple.shared,
                    **c.figures.as_dict(),
                    "per_frame": [f.as_dict() for f in c.per_frame],
                }
                for c in self.couples
            },
        }


def pair_pipelines(
    rig: Rig,
    pairs: Sequence[PairNames],
    *,
    vpc: RectifiedPairConfig | None = None,
    stereo: StereoParams | None = None,
    cache_dir: str | Path | None = None,
    rigs: Mapping[PairNames, Rig] | None = None,
) -> dict[PairNames, DepthPipeline]:
    """A depth pipeline per pair: ``vpc``'s projection and field settings (default today's) with
    the pair's cameras, on ``rigs[pair]`` where given, else ``rig``."""
    own = rigs or {}
    return {
        p: DepthPipeline(own.get(p, rig), pair_config(vpc, p), stereo, cache_dir, tune_malloc=False)
        for p in pairs
    }


def pair_ranges(pipeline: DepthPipeline, frame: Frame, index: int = 0) -> PairRange:
    """The pair's range on ``frame`` (its two cameras' images), measured over its view
    (:func:`rig.evaluate.consistency.view_mask`)."""
    left, right = pipeline.names
    for name in (left, right):
        if name not in frame:
            raise EvaluationError(f"frame {index}: no image of camera {name!r} (has {', '.join(frame)})")
    out = pipeline.process(frame[left], frame[right], seq=index)
    luts = pipeline.luts
    view = view_mask(luts[left].valid, luts[right].valid, pipeline.stereo.blind_band_px)
    return PairRange(pipeline.pair, out.range, view)


def consistency_study(
    rig: Rig,
    frames: Sequence[Frame],
    pairs: Sequence[PairNames] | None = None,
    *,
    vpc: RectifiedPairConfig | None = None,
    stereo: StereoParams | None = None,
    cache_dir: str | Path | None = None,
    rigs: Mapping[PairNames, Rig] | None = None,
    stride: int = 1,
    keep_ranges: bool = False,
    keep_points: bool = False,
    progress: Progress | None = None,
) -> ConsistencyStudy:
    """The study of ``rig`` on ``frames`` (each an image per camera): ``pairs`` (default
    :func:`rig.ring.adjacent_pairs`) through the depth pipeline with ``vpc``/``stereo`` (default
    today's; ``rigs``: a pair's own calibration), every couple compared on every ``stride``-th
    pixel of the source's range. ``keep_ranges``/``keep_points`` keep the range maps and the
    compared points for analysis."""
    if not frames:
        raise EvaluationError("the consistency study needs at least one frame")
    chosen = adjacent_pairs(rig, pairs) if pairs is not None else stereo_pairs(rig)
    pipelines = pair_pipelines(rig, chosen, vpc=vpc, stereo=stereo, cache_dir=cache_dir, rigs=rigs)
    solid = {p: pixel_solid_angles(pipe.pair.camera) for p, pipe in pipelines.items()}
    ranges: dict[PairNames, list[PairRange]] = {p: [] for p in chosen}
    total = len(frames) * len(chosen)
    for i, frame in enumerate(frames):
        for k, p in enumerate(chosen):
            ranges[p].append(pair_ranges(pipelines[p], frame, i))
            if progress is not None:
                progress(i * len(chosen) + k + 1, total)
    pair_results = [
        PairResult(
            p,
            pipelines[p],
            [range_coverage(r, solid[p]) for r in ranges[p]],
            ranges[p] if keep_ranges else [],
        )
        for p in chosen
    ]
    results = []
    for c in couples(chosen):
        per = [
            transfer_range(s, t, c.shared, stride)
            for s, t in zip(ranges[c.source], ranges[c.target], strict=True)
        ]
        pooled = TransferredRange.concat(per)
        frame_of = np.concatenate([np.full(t.r_source.size, i, dtype=np.intp) for i, t in enumerate(per)])
        results.append(
            CoupleResult(
                c,
                ConsistencyFigures.of(pooled),
                [ConsistencyFigures.of(t) for t in per],
                pooled if keep_points else None,
                frame_of if keep_points else None,
            )
        )
    return ConsistencyStudy(pair_results, results, len(frames))
