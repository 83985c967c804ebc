"""Ray-cast renderer: any ``calibration`` camera model at any pose, with exact depth.

For every pixel, ``supersample²`` sub-pixel rays (one per stratum of an s×s grid, see
:func:`subpixel_offsets`) are unprojected by the camera
model, moved into the world by ``T_world_cam``, intersected with the scene's rectangles, shaded
from the nearest rectangle's texture and box-filtered back to one pixel (anti-aliasing). Depth,
ray length and the validity mask come from the ray through the pixel centre, so they are exact,
not averaged. Work goes in chunks of image rows to bound memory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.geometry import is_rotation
from calibration.models import CameraModel
from rig.errors import SimulationError
from rig.sim.rays import camera_rays
from rig.sim.scene import Hits, Scene

__all__ = ["Render", "render", "render_range", "subpixel_offsets", "vignetting_factor"]

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

# Sub-pixel rays per chunk: ~200 MB peak for a 26-rectangle room, less for a plane.
DEFAULT_CHUNK_RAYS = 1 << 19


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


def subpixel_offsets(s: int) -> tuple[F64, F64]:
    """Sample offsets (du, dv), each (s, s) indexed [sub-row j, sub-column i], in pixels from the
    pixel centre: one sample per s×s stratum, on a sheared lattice so all s² samples have
    distinct u and distinct v. An axis-aligned edge then moves the pixel value in steps of 1/s²
    of its extent, not 1/s as on a regular grid (a 3× finer edge position for s = 3)."""
    j, i = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
    du = (i * s + j + 0.5) / (s * s) - 0.5
    dv = (j * s + i + 0.5) / (s * s) - 0.5
    return du.astype(np.float64), dv.astype(np.float64)


def _shade(scene: Scene, hits: Hits, channels: int, background: float) -> F32:
    """Texture values (M,) or (M, 3) for hits; ``background`` where a ray hits nothing."""
    shape = (hits.t.shape[0],) if channels == 1 else (hits.t.shape[0], 3)
    out = np.full(shape, background, dtype=np.float32)
    for r in np.unique(hits.rect_index[hits.rect_index >= 0]):
        sel = hits.rect_index == r
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


def _centre_hits(
    scene: Scene, camera: CameraModel, T: F64, rows: F64, cols: F64
) -> tuple[F64, F64, NDArray[np.bool_]]:
    """For the pixel centres of ``rows`` × ``cols`` (n·w,): the distance to the nearest surface
    along each ray (NaN: none or no ray), the rays (n·w, 3) in the camera frame, and valid."""
    vv, uu = np.meshgrid(rows, cols, indexing="ij")
    rays, ok = camera_rays(camera, np.stack([uu.ravel(), vv.ravel()], axis=1))
    hits = scene.intersect(T[:3, 3], rays[ok] @ T[:3, :3].T)
    t = np.full(ok.shape[0], np.nan)
    t[ok] = np.where(hits.rect_index >= 0, hits.t, np.nan)
    return t, rays, ok


def render_range(
    scene: Scene, camera: CameraModel, T_world_cam: ArrayLike, *, chunk_rays: int = DEFAULT_CHUNK_RAYS
) -> tuple[F32, NDArray[np.bool_]]:
    """Ground truth only: the distance (H, W) float32 m along each pixel-centre ray of ``camera``
    (any model, e.g. a rectified view) posed at ``T_world_cam`` to the nearest surface (NaN: no
    surface, or no ray), and the pixels that have a ray (H, W) bool. What :func:`render` gives
    as ``distance``, without shading."""
    T = np.asarray(T_world_cam, dtype=np.float64)
    _check(camera, T, 1, 0.0, 0.0, 0)
    h, w = camera.height, camera.width
    distance = np.empty((h, w), dtype=np.float32)
    valid = np.empty((h, w), dtype=bool)
    rows_per_chunk = max(1, int(chunk_rays) // w)
    cols = np.arange(w, dtype=np.float64)
    for r0 in range(0, h, rows_per_chunk):
        rows = np.arange(r0, min(h, r0 + rows_per_chunk), dtype=np.float64)
        t, _, ok = _centre_hits(scene, camera, T, rows, cols)
        distance[r0 : r0 + rows.size] = t.reshape(rows.size, w)
        valid[r0 : r0 + rows.size] = ok.reshape(rows.size, w)
    return distance, valid


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
    chunk_rays: int = DEFAULT_CHUNK_RAYS,
) -> Render:
    """Render ``scene`` through ``camera`` posed at ``T_world_cam`` (4, 4).

    ``noise_std``: gaussian sensor noise in grey levels (seeded by ``seed``; ``None`` = fresh);
    ``vignetting``: strength k of :func:`vignetting_factor`; ``color``: BGR output (grey
    textures become grey BGR); ``background``: the grey level where the lens sees nothing or a
    ray hits no surface.
    """
    T = np.asarray(T_world_cam, dtype=np.float64)
    _check(camera, T, supersample, float(noise_std), float(vignetting), background)
    s = int(supersample)
    h, w = camera.height, camera.width
    channels = 3 if color else 1
    R, origin = T[:3, :3], T[:3, 3]
    shade = np.empty((h, w, channels), dtype=np.float32)
    depth = np.full((h, w), np.nan, dtype=np.float32)
    distance = np.full((h, w), np.nan, dtype=np.float32)
    valid = np.zeros((h, w), dtype=bool)
    cos_theta = np.ones((h, w))
    du, dv = subpixel_offsets(s)
    rows_per_chunk = max(1, int(chunk_rays) // (w * s * s))
    cols = np.arange(w, dtype=np.float64)
    for r0 in range(0, h, rows_per_chunk):
        rows = np.arange(r0, min(h, r0 + rows_per_chunk), dtype=np.float64)
        n = rows.shape[0]
        # Pixel centres: validity, depth, ray length, off-axis angle.
        t, rays, ok = _centre_hits(scene, camera, T, rows, cols)
        sl = slice(r0, r0 + n)
        valid[sl] = ok.reshape(n, w)
        distance[sl] = t.reshape(n, w)
        depth[sl] = (t * rays[:, 2]).reshape(n, w)
        cos_theta[sl] = rays[:, 2].reshape(n, w)
        # Sub-pixel rays, (row, sub-row, column, sub-column) order so the box filter is a mean.
        sub_v = np.broadcast_to(rows[:, None, None, None] + dv[None, :, None, :], (n, s, w, s))
        sub_u = np.broadcast_to(cols[None, None, :, None] + du[None, :, None, :], (n, s, w, s))
        rays, ok = camera_rays(camera, np.stack([sub_u.ravel(), sub_v.ravel()], axis=1))
        samples = np.full((ok.shape[0], channels), float(background), dtype=np.float32)
        hits = scene.intersect(origin, rays[ok] @ R.T)
        samples[ok] = _shade(scene, hits, channels, float(background)).reshape(-1, channels)
        shade[sl] = samples.reshape(n, s, w, s, channels).mean(axis=(1, 3))
    if vignetting > 0:
        shade *= vignetting_factor(cos_theta, float(vignetting)).astype(np.float32)[:, :, None]
    if noise_std > 0:
        rng = np.random.default_rng(seed)
        shade += rng.normal(0.0, float(noise_std), shade.shape).astype(np.float32)
    image = np.clip(np.rint(shade), 0, 255).astype(np.uint8)
    image[~valid] = background
    return Render(image[:, :, 0] if channels == 1 else image, depth, distance, valid)
