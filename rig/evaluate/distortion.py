"""Distortion removal (the paper's Fig. 5 and 6): the left VPC image made through each
calibrated model's lookup table against the Reference camera's image of the same scene.

The scene is the demo room's geometry (walls, floor, ceiling, four boxes: edges at many depths)
seen from 0.5 m behind its origin, re-dressed like the paper's Unity scene: smooth shading on the
walls and ceiling, tiles on the floor and chequered boxes. The room's own fine multi-scale
textures (made for stereo matching) would make every resampled image differ everywhere and
hide the model; smooth surfaces with sharp edges show where a model misplaces pixels.

The fisheye view is rendered through the TRUE lens, without noise or vignetting, so the only
differences left are the model's (its calibration error) and the resampling's (the fisheye has
fewer pixels per degree than the VPC towards its rim). The rig's extrinsics are the true ones
for every model: like the paper, this isolates the intrinsic model. Our pseudo-model
``true_lens`` (the exact lens in the table) gives the resampling floor.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from calibration.geometry import make_transform
from calibration.models import CameraModel
from calibration.rig import Rig
from rig.errors import LutError
from rig.evaluate.metrics import image_difference
from rig.evaluate.renders import lut_box, render_in_box, union_box
from rig.lut import Lut, build_rectified_lut
from rig.rectified import RectifiedPair
from rig.sim import CheckerTexture, Scene, Texture, TexturedRect, make_texture, render, room_scene

__all__ = ["DifferenceResult", "DistortionStudy", "run_distortion_study"]

U8 = NDArray[np.uint8]
F64 = NDArray[np.float64]

#: Where the rig stands in the room (the demo's start of path: boxes ahead at 1.5–4 m).
ROOM_POSE: F64 = make_transform(np.eye(3), [0.0, 0.0, -0.5])


def comparison_scene(seed: int) -> Scene:
    """The room of :func:`rig.sim.room_scene` with smooth walls, a tiled floor and chequered
    boxes (see the module doc)."""
    room = room_scene(seed)
    rects = []
    for i, r in enumerate(room.rects):
        tex: Texture
        if r.name.startswith("box"):
            tex = CheckerTexture(40, 40, 0.1, 0.0, black=40.0, white=200.0)
        elif r.name == "floor":
            tex = CheckerTexture(40, 40, 0.5, 0.0, black=70.0, white=170.0)
        else:
            # 16 texels over 4 m, bilinear: gentle shading with no detail finer than ~25 cm.
            tex = make_texture("noise", seed + i, size_m=4.0, size_px=16)
        rects.append(TexturedRect(r.T_world_rect, r.size_m, tex, r.name))
    return Scene(rects, {**room.info, "kind": "comparison-room"})


@dataclass(frozen=True)
class DifferenceResult:
    """One model's VPC image against the Reference: mean absolute grey-level difference over the
    pixels its table maps into the lens (whole image and central 50 % × 50 %), that fraction,
    and the images (H, W) uint8; or ``error`` when no table could be built."""

    name: str
    mad_whole: float
    mad_central: float
    valid_frac: float
    rect_image: U8 | None
    diff_image: U8 | None
    error: str | None = None


@dataclass(frozen=True)
class DistortionStudy:
    reference: U8  # the Reference camera's image (H, W)
    results: dict[str, DifferenceResult]


def run_distortion_study(
    rig: Rig,
    pair: RectifiedPair,
    left_models: dict[str, CameraModel],
    *,
    seed: int,
    supersample: int,
    step: Callable[[str], None],
) -> DistortionStudy:
    """``left_models``: name -> the model used for the left camera's table (the true lens is
    rendered through ``rig.cameras[pair.left]``)."""
    name = pair.left
    lens = rig.cameras[name]
    R = pair.R_cam_rect[name]
    luts: dict[str, Lut] = {}
    errors: dict[str, str] = {}
    for label, model in left_models.items():
        try:
            luts[label] = build_rectified_lut(model, R, pair.camera)
        except LutError as err:
            errors[label] = str(err)
    scene = comparison_scene(seed)
    T_world_cam = ROOM_POSE @ rig.T_rig_cam[name]
    box = union_box(lut_box(lut, lens) for lut in luts.values()) if luts else (0, 0, 0, 0)
    fisheye = render_in_box(scene, lens, T_world_cam, box, supersample=supersample)
    step("rendering the room")
    reference = render(scene, pair.camera, ROOM_POSE @ pair.T_rig_rect[name], supersample=supersample).image
    step("rendering the room")
    results: dict[str, DifferenceResult] = {}
    for label in left_models:
        if label in errors:
            results[label] = DifferenceResult(label, math.nan, math.nan, 0.0, None, None, errors[label])
            continue
        lut = luts[label]
        rect_image = lut.remap(fisheye)
        whole, central, diff = image_difference(rect_image, reference, lut.valid)
        results[label] = DifferenceResult(label, whole, central, lut.valid_fraction, rect_image, diff)
    return DistortionStudy(reference, results)
