"""A camera's sub-pixel rays in tiles: what the renderer casts, the same at every pose.

A tile is a block of pixels (``tile_px`` square, smaller at the image's right and bottom
edges). For each, the ``supersample²`` sub-pixel rays per pixel (one per stratum of an s×s grid,
:func:`subpixel_offsets`) in the camera frame, which of them the lens sees, the pixel-centre
rays and the cone holding them all (for :meth:`rig.sim.raycast.CameraScene.candidates`). The
rays depend on the camera alone, so a :class:`RayGrid` built once serves every frame of a
recording (``cache=True`` keeps the tiles; without it they are made again each time, and only
one tile is in memory at a time).

For odd ``supersample`` the middle sample of the sheared lattice is exactly the pixel centre
(its offset is (s²/2)/s² - 1/2 = 0 in floating point too), so the centre's ray is that
sample's: it is cast once.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from calibration.models import CameraModel
from rig.sim.raycast import ray_cone
from rig.sim.rays import ray_function

__all__ = ["DEFAULT_TILE_PX", "RayGrid", "RayTile", "subpixel_offsets"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
Mask = NDArray[np.bool_]

#: Tile side in pixels: small enough that a tile's cone meets few rectangles, large enough that
#: the per-tile work of numpy calls stays small beside the rays'.
DEFAULT_TILE_PX = 32


def subpixel_offsets(s: int) -> tuple[F64, F64]:
    """Sample offsets (du, dv), each (s, s) indexed [sub-row j, sub-column i], in pixels from the
    pixel centre: one sample per s×s stratum, on a sheared lattice so all s² samples have
    distinct u and distinct v. An axis-aligned edge then moves the pixel value in steps of 1/s²
    of its extent, not 1/s as on a regular grid (a 3× finer edge position for s = 3)."""
    j, i = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
    du = (i * s + j + 0.5) / (s * s) - 0.5
    dv = (j * s + i + 0.5) / (s * s) - 0.5
    return du.astype(np.float64), dv.astype(np.float64)


@dataclass(frozen=True)
class RayTile:
    """Pixels ``rows`` × ``cols`` of a camera (n × w pixels) and their rays, camera frame;
    ``index`` its place among the grid's :attr:`RayGrid.count` tiles, row-major.

    samples_ok: (n·s·w·s,) which sub-pixel samples the lens sees, in (row, sub-row, column,
    sub-column) order, so the box filter is a mean over axes 1 and 3.
    rays: (M, 3) the rays of the samples the lens sees, in that order.
    centre_ok: (n·w,) which pixel centres the lens sees; centre_z: (n·w,) their rays' z (1 where
    not seen).
    centre_rays: (K, 3) the centres' rays the lens sees, or None when they are samples (odd s):
    then ``centre_in_samples`` (K,) indexes them in ``rays``.
    axis, cos_half: the cone around every ray of the tile (:func:`rig.sim.raycast.ray_cone`).
    """

    index: int
    rows: slice
    cols: slice
    samples_ok: Mask
    rays: F64
    centre_ok: Mask
    centre_z: F64
    centre_rays: F64 | None
    centre_in_samples: I64 | None
    axis: F64
    cos_half: float

    @property
    def shape(self) -> tuple[int, int]:
        return self.rows.stop - self.rows.start, self.cols.stop - self.cols.start


class RayGrid:
    """The tiles of ``camera`` at ``supersample``; ``cache`` keeps them for the next render."""

    def __init__(
        self, camera: CameraModel, supersample: int, *, tile_px: int = DEFAULT_TILE_PX, cache: bool = False
    ) -> None:
        self.camera = camera
        self.supersample = int(supersample)
        self.tile_px = max(1, int(tile_px))
        self.cache = cache
        self._tiles: list[RayTile] | None = None
        self.count = -(-camera.height // self.tile_px) * -(-camera.width // self.tile_px)
        self._rays = ray_function(camera)
        self._offsets = subpixel_offsets(self.supersample)

    def tiles(self) -> Iterator[RayTile]:
        """Every tile, row-major; those the lens does not see at all are left out."""
        if self._tiles is not None:
            yield from self._tiles
            return
        made: list[RayTile] = []
        h, w, t = self.camera.height, self.camera.width, self.tile_px
        slots = ((r0, c0) for r0 in range(0, h, t) for c0 in range(0, w, t))
        for index, (r0, c0) in enumerate(slots):
            tile = self._tile(index, slice(r0, min(h, r0 + t)), slice(c0, min(w, c0 + t)))
            if tile is None:
                continue
            if self.cache:
                made.append(tile)
            yield tile
        if self.cache:
            self._tiles = made

    def _tile(self, index: int, rows: slice, cols: slice) -> RayTile | None:
        s = self.supersample
        r = np.arange(rows.start, rows.stop, dtype=np.float64)
        c = np.arange(cols.start, cols.stop, dtype=np.float64)
        n, w = r.size, c.size
        du, dv = self._offsets
        sub_v = np.broadcast_to(r[:, None, None, None] + dv[None, :, None, :], (n, s, w, s))
        sub_u = np.broadcast_to(c[None, None, :, None] + du[None, :, None, :], (n, s, w, s))
        rays, ok = self._rays(np.stack([sub_u.ravel(), sub_v.ravel()], axis=1))
        if s % 2:
            # The middle sample (s//2, s//2) of each pixel is its centre.
            grid = np.arange(ok.size).reshape(n, s, w, s)[:, s // 2, :, s // 2].ravel()
            centre_ok = ok[grid]
            centre_z = np.where(centre_ok, rays[grid, 2], 1.0)
            # Position of each seen centre among the seen samples.
            centre_in_samples = (np.cumsum(ok) - 1)[grid[centre_ok]]
            centre_rays = None
            every = rays[ok]
        else:
            vv, uu = np.meshgrid(r, c, indexing="ij")
            c_rays, centre_ok = self._rays(np.stack([uu.ravel(), vv.ravel()], axis=1))
            centre_z = np.where(centre_ok, c_rays[:, 2], 1.0)
            centre_rays, centre_in_samples = c_rays[centre_ok], None
            every = np.concatenate([rays[ok], centre_rays])
        if every.shape[0] == 0:
            return None
        axis, cos_half = ray_cone(every)
        return RayTile(
            index,
            rows,
            cols,
            ok,
            rays[ok],
            centre_ok,
            centre_z,
            centre_rays,
            centre_in_samples,
            axis,
            cos_half,
        )
