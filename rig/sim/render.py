"""Ray-cast renderer: any ``calibration`` camera model at any pose, with exact depth.

For every pixel, ``supersample²`` sub-pixel rays (one per stratum of an s×s grid, see
:func:`subpixel_offsets`) are unprojected by the camera model (:class:`RayGrid`, in tiles of
neighbouring pixels), intersected in the camera frame with the scene's rectangles that the
tile's rays can reach (:class:`rig.sim.raycast.CameraScene`: exact culling, the same nearest hit
as testing every rectangle), shaded from the nearest rectangle's texture and box-filtered back to
one pixel (anti-aliasing). Depth, ray length and the validity mask come from the ray through the
pixel centre, so they are exact, not averaged. One tile is in memory at a time unless the
:class:`RayGrid` caches its rays for the next frame.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.geometry import is_rotation
from calibration.models import CameraModel
from rig.errors import SimulationError
from rig.sim.lens_effects import LensEffects, apply_lens
from rig.sim.raycast import CameraScene
from rig.sim.raygrid import DEFAULT_TILE_PX, RayGrid, subpixel_offsets
from rig.sim.scene import Hits, Scene

__all__ = [
    "Geometry",
    "RayGrid",
    "Render",
    "ViewProgress",
    "render",
    "render_geometry",
    "render_range",
    "subpixel_offsets",
    "vignetting_factor",
]

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Render:
    """One rendered view.

    image: uint8 (H, W) grey or (H, W, 3) BGR; ``background`` where the lens sees nothing.
    depth: float32 (H, W) z of the surface in the camera frame (m), NaN = no surface / no lens.
    distance: float32 (H, W) length of the pixel-centre ray to the surface (m), NaN likewise.
    valid: bool (H, W) pixels whose centre ray the lens sees (``camera.unproject`` valid).
    """

    image: NDArray[np.uint8]
    depth: F32
    distance: F32
    valid: NDArray[np.bool_]


def vignetting_factor(cos_theta: F64, strength: float) -> F64:
    """Brightness factor for rays at angle θ off the optical axis: ``1 - k (1 - cos⁴(θ/2))``.

    cos⁴-like and defined over a full 190° lens (a plain cos⁴θ would black out at 90°): with
    k = 1 a ray 90° off axis keeps 25 %, 95° keeps 21 %. ``cos_theta`` any shape.
    """
    half_cos2 = (1.0 + np.asarray(cos_theta, dtype=np.float64)) / 2.0  # cos²(θ/2)
    return 1.0 - strength * (1.0 - half_cos2 * half_cos2)


def _shade(scene: Scene, hits: Hits, channels: int, background: float) -> F32:
    """Texture values (M,) or (M, 3) for hits; ``background`` where a ray hits nothing."""
    shape = (hits.t.shape[0],) if channels == 1 else (hits.t.shape[0], 3)
    index = hits.rect_index
    if index.size and index[0] >= 0 and (index == index[0]).all():  # one rectangle: no selection
        return scene.rects[int(index[0])].texture.sample_as(hits.st, channels)
    out = np.full(shape, background, dtype=np.float32)
    for r in np.unique(index[index >= 0]):
        sel = index == r
        out[sel] = scene.rects[int(r)].texture.sample_as(hits.st[sel], channels)
    return out


def _check(
    camera: CameraModel, T: F64, supersample: int, noise_std: float, vignetting: float, background: int
) -> None:
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise SimulationError(f"render: T_world_cam must be a finite 4x4 matrix, got shape {T.shape}")
    R = T[:3, :3]
    if not is_rotation(R):
        raise SimulationError("render: T_world_cam is not a rigid transform")
    if isinstance(supersample, bool) or int(supersample) != supersample or not (1 <= supersample <= 16):
        raise SimulationError(f"render: supersample must be an integer in [1, 16], got {supersample!r}")
    if not (math.isfinite(noise_std) and noise_std >= 0):
        raise SimulationError(f"render: noise_std must be >= 0 grey levels, got {noise_std!r}")
    if not (math.isfinite(vignetting) and 0 <= vignetting <= 1):
        raise SimulationError(f"render: vignetting must be in [0, 1], got {vignetting!r}")
    if isinstance(background, bool) or int(background) != background or not (0 <= background <= 255):
        raise SimulationError(f"render: background must be a grey level 0..255, got {background!r}")


@dataclass(frozen=True)
class Geometry:
    """What the pixel-centre rays of a view hit: ``depth``, ``distance`` and ``valid`` as in
    :class:`Render`."""

    depth: F32
    distance: F32
    valid: NDArray[np.bool_]


#: ``progress(fraction)`` of one view's tiles done, after each tile.
ViewProgress = Callable[[float], None]


def _cast(
    scene: Scene,
    T: F64,
    grid: RayGrid,
    shade: F32 | None,
    background: float,
    progress: ViewProgress | None,
) -> tuple[Geometry, F64]:
    """Cast ``grid``'s rays into ``scene`` from the pose ``T``; fill ``shade`` (H, W, channels)
    with the box-filtered samples unless it is None. Returns the centre rays' geometry and the
    cosine of their angle off the optical axis (1 where the lens sees nothing)."""
    s = grid.supersample
    h, w = grid.camera.height, grid.camera.width
    depth = np.full((h, w), np.nan, dtype=np.float32)
    distance = np.full((h, w), np.nan, dtype=np.float32)
    valid = np.zeros((h, w), dtype=bool)
    cos_theta = np.ones((h, w))
    view = CameraScene(scene, T)
    for tile in grid.tiles():
        n, tw = tile.shape
        rects = view.candidates(tile.axis, tile.cos_half)
        hits = view.intersect(tile.rays, rects)
        if shade is not None:
            ch = shade.shape[2]
            samples = np.full((tile.samples_ok.size, ch), background, dtype=np.float32)
            samples[tile.samples_ok] = _shade(scene, hits, ch, background).reshape(-1, ch)
            shade[tile.rows, tile.cols] = samples.reshape(n, s, tw, s, ch).mean(axis=(1, 3))
        if tile.centre_rays is None:
            centre_t, centre_rect = hits.t[tile.centre_in_samples], hits.rect_index[tile.centre_in_samples]
        else:
            centre = view.intersect(tile.centre_rays, rects)
            centre_t, centre_rect = centre.t, centre.rect_index
        t = np.full(n * tw, np.nan)
        t[tile.centre_ok] = np.where(centre_rect >= 0, centre_t, np.nan)
        valid[tile.rows, tile.cols] = tile.centre_ok.reshape(n, tw)
        distance[tile.rows, tile.cols] = t.reshape(n, tw)
        depth[tile.rows, tile.cols] = (t * tile.centre_z).reshape(n, tw)
        cos_theta[tile.rows, tile.cols] = tile.centre_z.reshape(n, tw)
        if progress is not None:
            progress((tile.index + 1) / grid.count)
    return Geometry(depth, distance, valid), cos_theta


def render_geometry(
    scene: Scene,
    camera: CameraModel,
    T_world_cam: ArrayLike,
    *,
    tile_px: int = DEFAULT_TILE_PX,
    rays: RayGrid | None = None,
) -> Geometry:
    """Ground truth only: depth, distance and validity of each pixel-centre ray of ``camera``
    (any model, e.g. a rectified view) posed at ``T_world_cam``, as :func:`render` gives them,
    without shading. ``rays``: the camera's :class:`RayGrid` at supersample 1 to reuse."""
    T = np.asarray(T_world_cam, dtype=np.float64)
    _check(camera, T, 1, 0.0, 0.0, 0)
    return _cast(scene, T, _grid(camera, 1, tile_px, rays), None, 0.0, None)[0]


def _grid(camera: CameraModel, supersample: int, tile_px: int, rays: RayGrid | None) -> RayGrid:
    if rays is None:
        return RayGrid(camera, supersample, tile_px=tile_px)
    if rays.camera is not camera or rays.supersample != supersample:
        raise SimulationError("render: the ray grid is of another camera or supersampling")
    return rays


def render_range(
    scene: Scene, camera: CameraModel, T_world_cam: ArrayLike, *, tile_px: int = DEFAULT_TILE_PX
) -> tuple[F32, NDArray[np.bool_]]:
    """The distance (H, W) float32 m along each pixel-centre ray of ``camera`` posed at
    ``T_world_cam`` to the nearest surface (NaN: no surface, or no ray) and the pixels that have a
    ray (H, W) bool (:func:`render_geometry`)."""
    truth = render_geometry(scene, camera, T_world_cam, tile_px=tile_px)
    return truth.distance, truth.valid


def render(
    scene: Scene,
    camera: CameraModel,
    T_world_cam: ArrayLike,
    *,
    supersample: int = 3,
    noise_std: float = 0.0,
    vignetting: float = 0.0,
    seed: int | None = None,
    color: bool = False,
    background: int = 0,
    tile_px: int = DEFAULT_TILE_PX,
    rays: RayGrid | None = None,
    progress: ViewProgress | None = None,
    lens: LensEffects | None = None,
    camera_index: int = 0,
) -> Render:
    """Render ``scene`` through ``camera`` posed at ``T_world_cam`` (4, 4).

    ``noise_std``: gaussian sensor noise in grey levels (seeded by ``seed``; ``None`` = fresh);
    ``vignetting``: strength k of :func:`vignetting_factor`; ``color``: BGR output (grey
    textures become grey BGR); ``background``: the grey level where the lens sees nothing or a
    ray hits no surface. ``rays``: the camera's :class:`RayGrid` at ``supersample`` to reuse
    (one that caches its tiles makes the next render of the same camera skip the lens model).
    ``progress``: called with the fraction of the view done as the tiles finish. ``lens``: the
    lens and sensor effects (:mod:`rig.sim.lens_effects`) of the rig's ``camera_index``-th
    camera, applied before ``vignetting`` and ``noise_std``; None is the ideal lens.
    """
    T = np.asarray(T_world_cam, dtype=np.float64)
    _check(camera, T, supersample, float(noise_std), float(vignetting), background)
    grid = _grid(camera, int(supersample), tile_px, rays)
    shade = np.full((camera.height, camera.width, 3 if color else 1), float(background), dtype=np.float32)
    truth, cos_theta = _cast(scene, T, grid, shade, float(background), progress)
    rng = np.random.default_rng(seed)
    if lens is not None:
        shade = apply_lens(shade, cos_theta, camera.max_theta, lens, camera_index, rng)
    if vignetting > 0:
        shade *= vignetting_factor(cos_theta, float(vignetting)).astype(np.float32)[:, :, None]
    if noise_std > 0:
        shade += rng.normal(0.0, float(noise_std), shade.shape).astype(np.float32)
    image = np.clip(np.rint(shade), 0, 255).astype(np.uint8)
    image[~truth.valid] = background
    return Render(image[:, :, 0] if not color else image, truth.depth, truth.distance, truth.valid)
