"""A scene seen from one camera pose: its rectangles in the camera frame, and exact culling.

The renderer casts rays in tiles of neighbouring pixels. A tile's rays lie in a cone (axis,
half-angle); a rectangle can only be hit by a ray inside the pyramid its four edges span from the
camera, on the side of the camera its face is on. :meth:`CameraScene.candidates` keeps the
rectangles whose five bounding half-spaces each meet the tile's cone: a superset of the ones any
ray of the tile hits (it never drops a rectangle a ray could hit), so the nearest hit among the
candidates is the nearest hit in the whole scene. In the demo room that is 1–4 of 26 rectangles.

Rays are intersected in the camera frame (origin 0): the renderer's camera-frame rays need no
rotation, and a cached ray set serves every pose of the camera.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rig.sim.scene import Hits, RectArrays, Scene, intersect_rects

__all__ = ["CameraScene", "ray_cone"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

# Slack on the culling tests (the cosine of an angle): far above rounding, far below anything a
# ray could hit (a ray this close to a rectangle's edge plane misses it by 1e-9 of its distance).
_CULL_SLACK = 1e-9


def ray_cone(rays: F64) -> tuple[F64, float]:
    """The cone around unit ``rays`` (N, 3): its unit axis and the cosine of its half-angle
    (the smallest ``ray · axis``); -1 when the rays span more than a hemisphere around it."""
    axis = rays.sum(axis=0)
    norm = float(np.linalg.norm(axis))
    if norm == 0.0:
        return np.array([0.0, 0.0, 1.0]), -1.0
    axis /= norm
    return axis, float(np.min(rays @ axis))


class CameraScene:
    """``scene`` in the frame of a camera posed at ``T_world_cam`` (4, 4)."""

    def __init__(self, scene: Scene, T_world_cam: ArrayLike) -> None:
        T = np.asarray(T_world_cam, dtype=np.float64)
        R, o = T[:3, :3], T[:3, 3]
        centres, ux, uy, normal, half = scene.rect_arrays
        # World -> camera: p_cam = R^T (p - o), i.e. row vectors times R.
        self.rects: RectArrays = ((centres - o) @ R, ux @ R, uy @ R, normal @ R, half)
        self.planes = _bounding_planes(self.rects)  # (R, 5, 3)

    def candidates(self, axis: F64, cos_half: float) -> I64:
        """Indices of the rectangles a ray in the cone (``axis``, cosine ``cos_half`` of its
        half-angle, :func:`ray_cone`) may hit, ascending."""
        if cos_half <= 0.0:  # a cone wider than a hemisphere meets every half-space
            return np.arange(self.planes.shape[0])
        sin_half = float(np.sqrt(max(0.0, 1.0 - cos_half * cos_half)))
        # A cone meets the half-space {d: d·m >= 0} iff the angle from its axis to m is at most
        # 90° plus its half-angle, i.e. axis·m >= -sin(half-angle).
        reach = self.planes @ axis  # (R, 5)
        return np.flatnonzero((reach >= -sin_half - _CULL_SLACK).all(axis=1))

    def intersect(self, rays: F64, rects: I64) -> Hits:
        """Nearest hits of camera-frame ``rays`` (N, 3) among ``rects`` (indices, ascending);
        ``rect_index`` indexes the whole scene."""
        subset: RectArrays = tuple(a[rects] for a in self.rects)  # type: ignore[assignment]
        hits = intersect_rects(subset, np.zeros(3), rays)
        found = hits.rect_index >= 0
        index = np.where(found, rects[np.maximum(hits.rect_index, 0)] if rects.size else -1, -1)
        return Hits(hits.t, index, hits.st)


def _bounding_planes(rects: RectArrays) -> F64:
    """Per rectangle (R, 5, 3): the unit normals m of the half-spaces {d: d·m >= 0} whose
    intersection holds every direction from the origin (the camera) to a point of it: the planes
    through the origin and each edge, and its face turned to the camera. A zero normal (the
    camera on an edge's line or in the rectangle's plane) is no constraint."""
    centres, ux, uy, normal, half = rects
    hx, hy = ux * half[:, :1], uy * half[:, 1:]
    corners = np.stack([centres - hx - hy, centres + hx - hy, centres + hx + hy, centres - hx + hy], axis=1)
    edges = np.cross(corners, np.roll(corners, -1, axis=1))  # (R, 4, 3)
    # Orient each edge plane so the rectangle's centre is on its positive side.
    edges *= np.sign(np.einsum("rek,rk->re", edges, centres))[:, :, None]
    face = normal * np.sign(np.einsum("rk,rk->r", normal, centres))[:, None]
    planes = np.concatenate([edges, face[:, None, :]], axis=1)
    norms = np.linalg.norm(planes, axis=2, keepdims=True)
    scale = np.linalg.norm(centres, axis=1)[:, None, None] * np.linalg.norm(hx + hy, axis=1)[:, None, None]
    # Degenerate planes (relative to the rectangle's size and distance) constrain nothing.
    usable = norms > 1e-12 * np.maximum(scale, 1e-300)
    return np.where(usable, planes / np.where(usable, norms, 1.0), 0.0)
