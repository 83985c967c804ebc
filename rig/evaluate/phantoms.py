"""Phantom obstacles: depth nearer than half the truth, on rendered scenes made to provoke them.

A stereo matcher fooled by a repetitive texture matches a pixel with the texture's next period
instead of itself; the disparity it reports is one period too large, and the depth a fraction of
the truth: an obstacle that is not there, worse for a robot than a hole. This module renders
scenes with repetitive and low texture through a simulated rig, and measures per
:class:`~rig.stereo.StereoParams` the *phantom rate* (valid pixels whose depth is nearer than
half the truth, per valid pixel) and the *valid fraction* (valid pixels per pixel with a
surface) and the *lost rate* (valid pixels further than twice the truth: a real obstacle
placed too far), the figures the defaults are chosen by (``python -m bench.phantoms``, docs/stereo.md).

Scenes (:data:`SCENES`), all seen by the ``prototype`` rig (190° Kannala-Brandt lenses, 72 mm
baseline) through its honest lens (``lens="honest"``: blur growing to the rim, rim darkening,
per-camera exposure, sensor noise; ``"ideal"``: none):

* ``room-walk-0`` … ``room-walk-2``: the README's walkthrough, ``rig sim --preset prototype
  --scene room --frames 3`` (the demo room; its front wall's printed paper repeats every 2 m);
* ``bricks``: a brick wall 2 m ahead, turned 25°, its texture tile repeating every 0.6 m;
* ``stripes``: vertical bars every 8 cm (blinds, a radiator, a fence) 1.5 m ahead, turned 15°,
  with faint non-repeating stains;
* ``low-texture``: a wall 2.5 m ahead, turned 20°, whose texture spans ±3.5 grey levels;
* ``near-wall``: a well-textured wall 0.3 m ahead (the other side of the trade-off: a surface
  nearer than the disparity range reaches must come out as a hole, not as a far surface).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from calibration.geometry import make_transform, rot_y
from calibration.models import PinholeModel
from calibration.rig import Rig
from rig.depth import pixel_ray_norms
from rig.evaluate.renders import lut_box, render_in_box
from rig.lut import build_rectified_lut
from rig.rectified import RectifiedPair, RectifiedPairConfig, design_rectified_pair
from rig.sim import (
    ImageTexture,
    Scene,
    TexturedRect,
    get_preset,
    make_texture,
    room_path,
    room_scene,
)
from rig.sim.lens_effects import lens_for
from rig.sim.patterns import spectral_noise
from rig.sim.render import render_range

#: The rectified pair the phantom rates are measured on: the paper's 640×480, 90° pinhole pair,
#: whose depth (z) the scenes' truth is.
PHANTOM_VPC = RectifiedPairConfig(projection="pinhole")

__all__ = [
    "PHANTOM_FACTOR",
    "PHANTOM_VPC",
    "SCENES",
    "PhantomScene",
    "PhantomShot",
    "PhantomStats",
    "phantom_stats",
    "render_phantom_shot",
    "room_walk",
    "truth_depth",
]

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

#: A valid pixel whose depth is below this fraction of the truth is a phantom obstacle.
PHANTOM_FACTOR = 0.5


@dataclass(frozen=True)
class PhantomScene:
    """A scene and the rig's pose in it (``T_world_rig``, 4×4)."""

    name: str
    what: str
    build: Callable[[], Scene]
    T_world_rig: F64


def _wall(distance_m: float, yaw_deg: float, size_m: tuple[float, float], texture: ImageTexture) -> Scene:
    """A wall centred ``distance_m`` ahead of the rig, turned ``yaw_deg`` about the vertical."""
    R = rot_y(math.radians(yaw_deg))
    rect = TexturedRect(make_transform(R, [0.0, 0.0, distance_m]), size_m, texture, "wall")
    return Scene([rect], {"kind": "wall", "distance_m": distance_m, "yaw_deg": yaw_deg})


def _bricks() -> Scene:
    return _wall(2.0, 25.0, (12.0, 8.0), make_texture("bricks", 3, size_m=0.6, size_px=512))


def _stripes() -> Scene:
    # 0.8 m tile of 10 bars; stains of ±6 grey levels that do not repeat within the tile.
    size = 1024
    x = (np.arange(size) + 0.5) / size * 10.0
    bars = np.where((x % 1.0) < 0.5, 70.0, 185.0)[None, :].repeat(size, axis=0)
    stains = 6.0 * spectral_noise(np.random.default_rng(11), size, beta=1.2)
    image = (bars + stains).astype(np.float32)
    return _wall(1.5, 15.0, (10.0, 6.0), ImageTexture(image, (0.8, 0.8)))


def _low_texture() -> Scene:
    texture = make_texture("noise", 5, size_m=2.0, size_px=1024).tinted((120, 120, 120), (136, 136, 136))
    grey = ImageTexture(texture.image.mean(axis=2), texture.size_m)
    return _wall(2.5, 20.0, (12.0, 8.0), grey)


def _near_wall() -> Scene:
    return _wall(0.3, 10.0, (3.0, 2.0), make_texture("noise", 9, size_m=0.5, size_px=512))


def room_walk(index: int, count: int = 3) -> PhantomScene:
    """Frame ``index`` of ``count`` of ``rig sim --scene room --frames count`` (seed 0)."""
    name = f"room-walk-{index}" if count == 3 else f"room-walk-{index}-of-{count}"
    return PhantomScene(
        name,
        f"the walkthrough room, frame {index} of {count}",
        lambda: room_scene(0),
        room_path(index, count),
    )


SCENES: dict[str, PhantomScene] = {
    s.name: s
    for s in (
        room_walk(0),
        room_walk(1),
        room_walk(2),
        PhantomScene("bricks", "brick wall, 2 m, turned 25°, tile 0.6 m", _bricks, np.eye(4)),
        PhantomScene("stripes", "bars every 8 cm, 1.5 m, turned 15°", _stripes, np.eye(4)),
        PhantomScene("low-texture", "wall of ±3.5 grey levels, 2.5 m, turned 20°", _low_texture, np.eye(4)),
        PhantomScene("near-wall", "textured wall 0.3 m ahead, turned 10°", _near_wall, np.eye(4)),
    )
}


@dataclass(frozen=True)
class PhantomShot:
    """A rendered fisheye pair (full size, only what the VPC tables read is rendered) and the
    true depth (H, W) of its left VPC, NaN where no surface."""

    name: str
    left: U8
    right: U8
    truth: F32
    rig: Rig
    pair: RectifiedPair


def truth_depth(scene: Scene, pair: RectifiedPair, T_world_rig: F64) -> F32:
    """What the pair's depth map holds for the nearest surface, per rectified pixel (NaN: none):
    z in the left VPC frame for a pinhole pair, the range along the ray for a lat-lon pair."""
    distance, _ = render_range(scene, pair.camera, T_world_rig @ pair.T_rig_rect[pair.left])
    if isinstance(pair.camera, PinholeModel):
        return np.asarray(distance / pixel_ray_norms(pair.camera), dtype=np.float32)
    return distance


def render_phantom_shot(
    which: str | PhantomScene,
    *,
    vpc: RectifiedPairConfig | None = None,
    blind_band_px: int = 0,
    supersample: int = 2,
    seed: int = 0,
    lens: str = "honest",
) -> PhantomShot:
    """A scene (or a name of :data:`SCENES`) through the ``prototype`` rig and its ``lens``
    (honest or ideal; noise seeded); by default on the 640×480 pinhole pair (:data:`PHANTOM_VPC`).
    ``blind_band_px``: the matcher's unmatched columns, which a lat-lon pair's default field
    adds (the pipeline's pair for those stereo parameters)."""
    spec = SCENES[which] if isinstance(which, str) else which
    name = spec.name
    preset = get_preset("prototype")
    rig = preset.rig
    effects = lens_for(lens, preset.lens)
    pair = design_rectified_pair(rig, vpc or PHANTOM_VPC, blind_band_px=blind_band_px)
    scene = spec.build()
    images = []
    for i, cam in enumerate((pair.left, pair.right)):
        model = rig.cameras[cam]
        box = lut_box(build_rectified_lut(model, pair.R_cam_rect[cam], pair.camera), model)
        images.append(
            render_in_box(
                scene,
                model,
                spec.T_world_rig @ rig.T_rig_cam[cam],
                box,
                supersample=supersample,
                seed=seed * 2 + i,
                lens=effects,
                camera_index=list(rig.cameras).index(cam),
            )
        )
    return PhantomShot(name, images[0], images[1], truth_depth(scene, pair, spec.T_world_rig), rig, pair)


@dataclass(frozen=True)
class PhantomStats:
    """Counts over one depth map: pixels with a surface, valid ones among them, phantoms
    (nearer than half the truth) and lost surfaces (further than twice the truth)."""

    surface: int
    valid: int
    phantoms: int
    lost: int

    @property
    def valid_fraction(self) -> float:
        return self.valid / self.surface if self.surface else 0.0

    @property
    def phantom_rate(self) -> float:
        """Phantoms per valid pixel."""
        return self.phantoms / self.valid if self.valid else 0.0

    @property
    def lost_rate(self) -> float:
        """Lost surfaces per valid pixel."""
        return self.lost / self.valid if self.valid else 0.0

    def __add__(self, other: PhantomStats) -> PhantomStats:
        return PhantomStats(
            self.surface + other.surface,
            self.valid + other.valid,
            self.phantoms + other.phantoms,
            self.lost + other.lost,
        )


def phantom_stats(depth: F32, valid: NDArray[np.bool_], truth: F32) -> PhantomStats:
    """Phantoms (valid, depth < :data:`PHANTOM_FACTOR` × truth) among the valid pixels with a
    surface; ``depth`` and ``truth`` (H, W) metres, NaN invalid / no surface."""
    surface = np.isfinite(truth)
    ok = valid & surface
    with np.errstate(invalid="ignore"):
        near = ok & (depth < PHANTOM_FACTOR * truth)
        far = ok & (depth > truth / PHANTOM_FACTOR)
    return PhantomStats(int(surface.sum()), int(ok.sum()), int(near.sum()), int(far.sum()))
