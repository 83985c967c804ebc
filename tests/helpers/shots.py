"""Rendered stereo shots with their ground truth, shared by the stereo, pipeline, service and
bench tests (cached per process, and rendered once per test run: tests.helpers.shared).

Only the part of each fisheye image that the VPC's lookup table reads is rendered
(``rig.evaluate.renders.render_in_box``: the same lens with its principal point moved sees the
same ray at every pixel); the rest stays background (0), which the table never samples. That
makes full-size prototype renders affordable in tests.

The shots are the ideal lens with the simple sensor model (gaussian noise, vignetting) the callers
choose: the matcher and the pipeline are these tests' subject. The honest lens
(``rig.sim.lens_effects``) is what ``rig sim`` and the studies render by default.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from calibration.geometry import make_transform
from calibration.models import PinholeModel
from calibration.rig import Rig
from rig.evaluate.renders import lut_box, render_in_box
from rig.lut import build_rectified_lut
from rig.rectified import RectifiedPair, RectifiedPairConfig, design_rectified_pair
from rig.sim import Scene, divergent_rig, get_preset, plane_scene, render, room_scene
from tests.helpers.shared import once_per_run

__all__ = [
    "PINHOLE",
    "StereoShot",
    "add_noise",
    "central_box",
    "mount_rig",
    "plane_shot",
    "prototype_rig",
    "render_for_pair",
    "room_shot",
]

U8 = NDArray[np.uint8]
F32 = NDArray[np.float32]
PINHOLE = RectifiedPairConfig(projection="pinhole")  # the shots' default pair: the paper's 640x480, 90°


@dataclass(frozen=True)
class StereoShot:
    """A rendered fisheye pair and the ground truth of its left VPC."""

    left: U8
    right: U8
    depth: F32  # (H, W) z in the left VPC frame, NaN where no surface
    pair: RectifiedPair
    rig: Rig

    @property
    def disparity(self) -> F32:
        out: F32 = (self.pair.fx * self.pair.baseline_m / self.depth).astype(np.float32)
        return out


@functools.lru_cache(maxsize=4)
def prototype_rig(scale: float = 1.0) -> Rig:
    return get_preset("prototype").scaled(scale).rig


@functools.lru_cache(maxsize=4)
def mount_rig(scale: float, angle_deg: float, pitch_deg: float) -> Rig:
    """The prototype's lenses on a non-ideal mount (renderer's divergent_rig)."""
    base = prototype_rig(scale)
    return divergent_rig(base.cameras["left"], base.cameras["right"], base.baseline(), angle_deg, pitch_deg)


def render_for_pair(
    scene: Scene,
    rig: Rig,
    name: str,
    pair: RectifiedPair,
    T_world_rig: NDArray[np.float64],
    supersample: int,
    noise_std: float = 0.0,
    vignetting: float = 0.0,
    seed: int = 0,
) -> U8:
    """Full-size fisheye image of camera ``name`` with only the VPC's source region rendered
    (noise and vignetting as the renderer applies them, per pixel)."""
    model = rig.cameras[name]
    box = lut_box(build_rectified_lut(model, pair.R_cam_rect[name], pair.camera), model)
    return render_in_box(
        scene, model, T_world_rig @ rig.T_rig_cam[name], box,
        supersample=supersample, noise_std=noise_std, vignetting=vignetting, seed=seed,
    )  # fmt: skip


def _shot_rig(scale: float, angle_deg: float, pitch_deg: float) -> Rig:
    """The prototype rig, or a mount of another divergence or pitch."""
    if (angle_deg, pitch_deg) == (90.0, 0.0):
        return prototype_rig(scale)
    return mount_rig(scale, angle_deg, pitch_deg)


def _reference_depth(scene: Scene, camera: PinholeModel, T_world_rect: NDArray[np.float64]) -> F32:
    return render(scene, camera, T_world_rect, supersample=1).depth


@functools.lru_cache(maxsize=32)
@once_per_run
def plane_shot(
    k_baselines: float,
    *,
    scale: float = 0.5,
    vpc: RectifiedPairConfig | None = None,
    texture: int = 0,
    seed: int = 0,
    supersample: int = 3,
    angle_deg: float = 90.0,
    pitch_deg: float = 0.0,
    noise_std: float = 0.0,
    vignetting: float = 0.0,
) -> StereoShot:
    """The paper's target: a textured fronto-parallel plane ``k_baselines`` baselines ahead."""
    rig = _shot_rig(scale, angle_deg, pitch_deg)
    pair = design_rectified_pair(rig, vpc or PINHOLE)
    scene = plane_scene(k_baselines * rig.baseline(), texture=texture, seed=seed)
    eye = np.eye(4)
    left, right = (
        render_for_pair(scene, rig, n, pair, eye, supersample, noise_std, vignetting, seed * 2 + i)
        for i, n in enumerate(("left", "right"))
    )
    depth = _reference_depth(scene, pair.camera, pair.T_rig_rect[pair.left])
    return StereoShot(left, right, depth, pair, rig)


@functools.lru_cache(maxsize=8)
@once_per_run
def room_shot(
    seed: int = 0,
    *,
    scale: float = 0.5,
    vpc: RectifiedPairConfig | None = None,
    supersample: int = 2,
    x_m: float = 0.0,
    angle_deg: float = 90.0,
    pitch_deg: float = 0.0,
) -> StereoShot:
    """The demo room (walls and boxes: depth edges and occlusions), rig at (x_m, 0, -0.5)."""
    rig = _shot_rig(scale, angle_deg, pitch_deg)
    pair = design_rectified_pair(rig, vpc or PINHOLE)
    scene = room_scene(seed)
    T = make_transform(np.eye(3), [x_m, 0.0, -0.5])
    left, right = (render_for_pair(scene, rig, n, pair, T, supersample) for n in ("left", "right"))
    depth = _reference_depth(scene, pair.camera, T @ pair.T_rig_rect[pair.left])
    return StereoShot(left, right, depth, pair, rig)


def add_noise(image: U8, std: float, seed: int) -> U8:
    """Gaussian sensor noise (grey levels), rounded and clipped like the renderer's."""
    rng = np.random.default_rng(seed)
    noisy = image.astype(np.float32) + rng.normal(0.0, std, image.shape).astype(np.float32)
    out: U8 = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    return out


def central_box(shape: tuple[int, ...]) -> tuple[slice, slice]:
    """The central 50 % × 50 % of an image."""
    h, w = shape[:2]
    return slice(h // 4, h - h // 4), slice(w // 4, w - w // 4)
