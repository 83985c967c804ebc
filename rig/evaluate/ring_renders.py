"""One rendered frame of a rig of N cameras with the exact range of every stereo pair
(docs/ring.md): each camera rendered as ``rig sim`` renders a pair's left and right, only where
its pairs' lookup tables read (:func:`rig.evaluate.renders.render_in_box`), and each pair's
ground truth through its left rectified view (:func:`rig.sim.render.render_range`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from calibration.rig import Rig
from rig.errors import EvaluationError
from rig.evaluate.renders import lut_box, render_in_box, union_box
from rig.pipeline import DepthPipeline
from rig.ring import PairNames
from rig.sim.lens_effects import LensEffects
from rig.sim.render import render_range
from rig.sim.scene import Scene

__all__ = ["RigShot", "render_rig_shot"]

U8 = NDArray[np.uint8]
F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


@dataclass(frozen=True)
class RigShot:
    """``images[camera]``: its fisheye image (gray uint8); ``truth[pair]``: the exact range
    (H, W) float32 m along each of the pair's left rectified pixels' rays (NaN: no surface)."""

    images: dict[str, U8]
    truth: dict[PairNames, F32]
    T_world_rig: F64


def render_rig_shot(
    scene: Scene,
    rig: Rig,
    pipelines: Mapping[PairNames, DepthPipeline],
    T_world_rig: F64,
    *,
    supersample: int = 3,
    noise_std: float = 0.0,
    vignetting: float = 0.0,
    seed: int = 0,
    lens: LensEffects | None = None,
) -> RigShot:
    """``scene`` seen by every camera of ``pipelines``' pairs (of ``rig``, posed at
    ``T_world_rig``), each camera seeded ``seed`` + its index in ``rig`` and through ``lens``
    (None: the ideal lens) as the rig's camera of that index, and each pair's ground truth (see
    the module doc)."""
    if not pipelines:
        raise EvaluationError("render: no stereo pairs to render for")
    boxes: dict[str, list[tuple[int, int, int, int]]] = {}
    for (left, right), pipe in pipelines.items():
        for name in (left, right):
            boxes.setdefault(name, []).append(lut_box(pipe.luts[name], rig.cameras[name]))
    images = {
        name: render_in_box(
            scene,
            rig.cameras[name],
            T_world_rig @ rig.T_rig_cam[name],
            union_box(boxes[name]),
            supersample=supersample,
            noise_std=noise_std,
            vignetting=vignetting,
            seed=seed + rig.names.index(name),
            lens=lens,
            camera_index=rig.names.index(name),
        )
        for name in rig.names
        if name in boxes
    }
    truth = {
        p: render_range(scene, pipe.pair.camera, T_world_rig @ pipe.pair.T_rig_rect[pipe.pair.left])[0]
        for p, pipe in pipelines.items()
    }
    return RigShot(images, truth, np.asarray(T_world_rig, dtype=np.float64))
