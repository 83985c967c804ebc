"""The depth pipeline of a rig of N cameras: one :class:`~rig.pipeline.DepthPipeline` per stereo
pair (:func:`rig.ring.stereo_pairs`: from the geometry, or rig.yaml's ``pairs:``), each today's
whole pipeline (its rectified pair, lookup tables in the cache, stereo, range, confidence), and
their ranges fused into one 360° range panorama about the rig (:mod:`rig.panorama`).

``RigPipeline(rig, config, stereo).process({camera: image})`` returns a :class:`RigFrame`: each
pair's :class:`~rig.pipeline.DepthFrame` by its name (``"A-B"``: :func:`rig.ring.pair_label`) and
the :class:`~rig.panorama.PanoramaFrame`. ``config`` is the rectified pair's settings for every
pair; its ``left``/``right`` are replaced by each pair's cameras. Over a recording the pairs run
on the staged executor (:mod:`rig.rig_depth`); :meth:`RigPipeline.fuse` then makes the panorama
of a set's finished pairs.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from calibration.rig import Rig
from rig.errors import ConfigError, PipelineError
from rig.panorama import DEFAULT_PANORAMA_PX_PER_DEG, PairOutput, PanoramaFrame, PanoramaSpec, fuse_panorama
from rig.pipeline import DepthFrame, DepthPipeline
from rig.rectified import RectifiedPairConfig
from rig.ring import PairNames, adjacent_pairs, pair_label, stereo_pairs
from rig.stereo import StereoParams

__all__ = ["RigFrame", "RigPipeline", "pair_config"]

U8 = NDArray[np.uint8]


def pair_config(config: RectifiedPairConfig | None, names: PairNames) -> RectifiedPairConfig:
    """``config`` (default today's) for the pair of cameras ``names`` (its ``left``, ``right``)."""
    base = config or RectifiedPairConfig()
    return RectifiedPairConfig.model_validate(
        {**base.model_dump(exclude_defaults=True), "left": names[0], "right": names[1]}
    )


@dataclass
class RigFrame:
    """One processed frame set: ``pairs[name]`` each pair's depth (in the rig's pair order),
    ``panorama`` their fusion; ``timings_ms``: each pair's ``total`` under its name, the fusion's
    as ``panorama`` and their sum as ``total`` (processing time, :class:`DepthFrame`'s
    convention)."""

    seq: int
    ts_ns: int
    pairs: dict[str, DepthFrame]
    panorama: PanoramaFrame
    timings_ms: dict[str, float] = field(default_factory=dict)


class RigPipeline:
    """Depth of every stereo pair of ``rig`` and their panorama (see the module doc). ``pairs``
    overrides the rig's pairs; ``panorama_px_per_deg`` is the panorama's resolution. The other
    arguments are :class:`DepthPipeline`'s, for every pair."""

    def __init__(
        self,
        rig: Rig,
        config: RectifiedPairConfig | None = None,
        stereo: StereoParams | None = None,
        cache_dir: str | Path | None = None,
        *,
        pairs: Sequence[PairNames] | None = None,
        panorama_px_per_deg: float = DEFAULT_PANORAMA_PX_PER_DEG,
        tune_malloc: bool = True,
        log_field_warnings: bool = True,
    ) -> None:
        chosen = adjacent_pairs(rig, pairs) if pairs is not None else stereo_pairs(rig)
        if not chosen:
            raise ConfigError(
                f"rig: no two of its cameras ({', '.join(rig.names)}) see a common direction: no stereo pair"
            )
        self.rig = rig
        self.config = config or RectifiedPairConfig()
        self.panorama = PanoramaSpec.for_rig(rig, panorama_px_per_deg)
        self.pipelines: dict[str, DepthPipeline] = {}
        for i, names in enumerate(chosen):
            self.pipelines[pair_label(names)] = DepthPipeline(
                rig,
                pair_config(config, names),
                stereo,
                cache_dir,
                tune_malloc=tune_malloc and i == 0,
                log_field_warnings=log_field_warnings,
            )

    @property
    def labels(self) -> list[str]:
        """The pairs' names (``"A-B"``), in order."""
        return list(self.pipelines)

    @property
    def pair_names(self) -> list[PairNames]:
        return [p.names for p in self.pipelines.values()]

    @property
    def cameras(self) -> list[str]:
        """The cameras the pairs use, in the rig's order."""
        used = {n for p in self.pipelines.values() for n in p.names}
        return [n for n in self.rig.names if n in used]

    @property
    def first(self) -> DepthPipeline:
        """The first pair's pipeline (the one ``/range`` serves by default)."""
        return next(iter(self.pipelines.values()))

    def pipeline(self, label: str) -> DepthPipeline:
        """The pipeline of pair ``label``; ConfigError listing the pairs otherwise."""
        try:
            return self.pipelines[label]
        except KeyError:
            raise ConfigError(f"no pair {label!r}; the rig's pairs: {', '.join(self.pipelines)}") from None

    # ----- processing --------------------------------------------------------------------------
    def process(self, frames: Mapping[str, U8], seq: int = 0, ts_ns: int = 0) -> RigFrame:
        """Depth of every pair on ``frames`` (an image per camera), one after the other, and the
        panorama."""
        missing = [n for n in self.cameras if n not in frames]
        if missing:
            raise PipelineError(f"no image of camera {', '.join(missing)} (got {', '.join(frames)})")
        out = {
            label: p.process(frames[p.names[0]], frames[p.names[1]], seq, ts_ns)
            for label, p in self.pipelines.items()
        }
        return self.finish(out, seq, ts_ns)

    def finish(self, pairs: Mapping[str, DepthFrame], seq: int, ts_ns: int) -> RigFrame:
        """The :class:`RigFrame` of a set's finished pairs (every pair of :attr:`labels`)."""
        t0 = time.perf_counter()
        panorama = self.fuse(pairs)
        fuse_ms = (time.perf_counter() - t0) * 1e3
        timings = {label: f.timings_ms.get("total", 0.0) for label, f in pairs.items()}
        timings["panorama"] = fuse_ms
        timings["total"] = sum(timings.values())
        return RigFrame(seq, ts_ns, {label: pairs[label] for label in self.labels}, panorama, timings)

    def outputs(self, pairs: Mapping[str, DepthFrame]) -> list[PairOutput]:
        """The pairs' results as the fusion takes them, in :attr:`labels` order."""
        missing = [label for label in self.labels if label not in pairs]
        if missing:
            raise PipelineError(f"panorama: no depth of pair {', '.join(missing)}")
        out = []
        for label, p in self.pipelines.items():
            frame, now = pairs[label], p.in_effect
            out.append(
                PairOutput(
                    label,
                    now.pair,
                    frame.range,
                    frame.disparity,
                    frame.confidence,
                    now.stereo.confidence_sigma,
                )
            )
        return out

    def fuse(self, pairs: Mapping[str, DepthFrame]) -> PanoramaFrame:
        """The panorama of one set's pairs (:func:`rig.panorama.fuse_panorama`)."""
        return fuse_panorama(self.panorama, self.outputs(pairs))

    # ----- outputs -----------------------------------------------------------------------------
    def point_cloud(self, frame: RigFrame, stride: int = 1) -> tuple[NDArray[np.float32], U8]:
        """The fused cloud: the panorama's points (N, 3) float32 in the rig frame, every
        ``stride``-th pixel of each axis, coloured (N, 3) uint8 RGB from the left rectified image of
        the pair each point's range came from."""
        spec, pano = self.panorama, frame.panorama
        rays = spec.rays_rig.reshape((*pano.range.shape, 3))[::stride, ::stride].reshape(-1, 3)
        rng = pano.range[::stride, ::stride].reshape(-1).astype(np.float64)
        source = pano.source[::stride, ::stride].reshape(-1)
        ok = np.isfinite(rng) & (source >= 0)
        points = spec.origin + rays[ok] * rng[ok, None]
        colors = np.zeros((points.shape[0], 3), np.uint8)
        for index, (label, p) in enumerate(self.pipelines.items()):
            mine = source[ok] == index
            if mine.any():
                colors[mine] = _colours(p, frame.pairs[label].left_rect, points[mine])
        return points.astype(np.float32), colors


def _colours(pipeline: DepthPipeline, image: U8, points: NDArray[np.float64]) -> U8:
    """RGB (N, 3) of rig-frame ``points`` in the pair's left rectified ``image`` (nearest pixel)."""
    pair = pipeline.pair
    T = pair.T_rig_rect[pair.left]
    q, _ = pair.camera.project((points - T[:3, 3]) @ T[:3, :3], in_image=False)
    h, w = image.shape[:2]
    u = np.clip(np.rint(q[:, 0]).astype(np.intp), 0, w - 1)
    v = np.clip(np.rint(q[:, 1]).astype(np.intp), 0, h - 1)
    px = image[v, u]
    return np.repeat(px[:, None], 3, axis=1) if image.ndim == 2 else np.ascontiguousarray(px[:, ::-1])
