"""The directions both lenses of a pair see, in azimuth and elevation of the rectified frame.

In the rectified frame (x along the baseline, z forward, y = z × x) a direction has azimuth
``asin(x)`` (the lat-lon image's column) and elevation ``atan2(y, z)`` (its row, the epipolar
plane), the angles of :class:`calibration.models.LatLonModel`. The overlap is sampled on an even
grid of both angles: a direction is in it when each fisheye model projects it into its image
(within the lens's field, e.g. 95° off its axis for a 190° lens). Directions, not points: the
baseline's parallax moves the edge of what both see by less than ``B / range`` radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.models import CameraModel, LatLonModel
from calibration.rig import Rig
from rig.errors import ConfigError

__all__ = ["DEFAULT_STEP_DEG", "Overlap", "image_border", "overlap", "pixel_solid_angles", "region_outline"]

F64 = NDArray[np.float64]

#: Grid step for the lat-lon field's bounds: the bounds are one step wider than the last direction
#: found inside, so that the field holds the whole overlap (a few more pixels at 5 px/deg).
DEFAULT_STEP_DEG = 0.5
# The poles (looking along the baseline) have no epipolar plane.
_POLE_MARGIN_DEG = 1.0


@dataclass(frozen=True)
class Overlap:
    """Directions both lenses see, on a grid of ``step`` radians: ``inside`` (n_el, n_az) over
    azimuths ``az`` (n_az,) and elevations ``el`` (n_el,) (radians, cell centres), and its
    bounds and solid angle."""

    az: F64
    el: F64
    inside: NDArray[np.bool_]
    step: float

    @property
    def solid_angle_sr(self) -> float:
        """Steradians of the overlap: each cell is ``cos(az)·step²`` of the sphere."""
        weights = np.cos(self.az)[None, :] * self.step**2
        return float((self.inside * weights).sum())

    def bounds(self) -> tuple[float, float, float, float]:
        """(az_lo, az_hi, el_lo, el_hi) radians: the cells inside, widened by one step each way
        (clipped to the grid)."""
        cols = np.flatnonzero(self.inside.any(axis=0))
        rows = np.flatnonzero(self.inside.any(axis=1))
        half = self.step / 2.0
        return (
            max(self.az[0] - half, self.az[cols[0]] - half - self.step),
            min(self.az[-1] + half, self.az[cols[-1]] + half + self.step),
            max(self.el[0] - half, self.el[rows[0]] - half - self.step),
            min(self.el[-1] + half, self.el[rows[-1]] + half + self.step),
        )

    def fraction_inside(self, az_lo: float, az_hi: float, el_lo: float, el_hi: float) -> float:
        """Fraction of the solid angle of the box ``[az_lo, az_hi] × [el_lo, el_hi]`` (radians)
        that the overlap covers."""
        in_az = (self.az >= az_lo) & (self.az <= az_hi)
        in_el = (self.el >= el_lo) & (self.el <= el_hi)
        weights = np.cos(self.az) * in_az
        box = float(weights.sum() * in_el.sum())
        covered = float((self.inside[in_el] * weights[None, :]).sum())
        return covered / box if box > 0 else 0.0


def overlap(rig: Rig, R_rig_rect: F64, left: str, right: str, step_deg: float = DEFAULT_STEP_DEG) -> Overlap:
    """The overlap of cameras ``left`` and ``right`` of ``rig`` in the rectified frame
    ``R_rig_rect`` (3, 3), on a grid of ``step_deg``. Raises :class:`ConfigError` when the two
    lenses see no common direction."""
    step = math.radians(step_deg)
    pole = math.pi / 2.0 - math.radians(_POLE_MARGIN_DEG)
    az = np.arange(-pole + step / 2.0, pole, step)
    el = np.arange(-math.pi + step / 2.0, math.pi, step)
    cos_az = np.cos(az)[None, :]
    x = np.broadcast_to(np.sin(az)[None, :], (el.size, az.size))
    y = cos_az * np.sin(el)[:, None]
    z = cos_az * np.cos(el)[:, None]
    inside = np.ones((el.size, az.size), dtype=bool)
    for name in (left, right):
        R = rig.T_rig_cam[name][:3, :3].T @ R_rig_rect  # rectified -> camera
        X, Y, Z = (R[i, 0] * x + R[i, 1] * y + R[i, 2] * z for i in range(3))
        inside &= rig.cameras[name].project_xyz(X, Y, Z)[2]
    if not inside.any():
        raise ConfigError(
            f"vpc: cameras '{left}' and '{right}' see no common direction: there is no stereo overlap "
            "(check the calibration's poses and the lenses' fields of view)"
        )
    return Overlap(az, el, inside, step)


def pixel_solid_angles(camera: CameraModel) -> F64:
    """Solid angle (H, W) in steradians that each pixel of ``camera`` (any model with a ray for
    every pixel, e.g. a rectified view) spans: ``|∂r/∂u × ∂r/∂v|`` of its unit ray ``r``, the
    derivatives as differences across the pixel (half a pixel either side). Closed forms:
    ``cos(azimuth)/(fx·fy)`` for a lat-lon view, ``(1 + x_n² + y_n²)^(−3/2)/(fx·fy)`` for a
    pinhole. A lat-lon view's differences have one of their own, ``4·sin(1/2fx)·sin(1/2fy)·|cos(azimuth)|``
    (each is a chord, and the two are orthogonal), which is used for it: the same values without
    unprojecting four rays per pixel. Pixels past the poles (azimuth beyond ±90°) have no ray: 0."""
    if isinstance(camera, LatLonModel):
        chords = 4.0 * math.sin(0.5 / camera.fx) * math.sin(0.5 / camera.fy)
        az = camera.azimuths()
        per_column = np.where(np.abs(az) <= math.pi / 2.0, chords * np.cos(az), 0.0)
        return np.repeat(per_column[None, :], camera.height, axis=0)
    h, w = camera.height, camera.width
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)

    def rays(du: float, dv: float) -> F64:
        pix = np.stack([(u + du).ravel(), (v + dv).ravel()], axis=1)
        r, _ = camera.unproject(pix, in_image=False)
        return r.reshape(h, w, 3)

    along_u = rays(0.5, 0.0) - rays(-0.5, 0.0)
    along_v = rays(0.0, 0.5) - rays(0.0, -0.5)
    out: F64 = np.linalg.norm(np.cross(along_u, along_v), axis=2)
    return out


def image_border(width: int, height: int, samples: int) -> F64:
    """Pixel centres (4·samples, 2) along an image's border: the top edge left to right, the
    right edge top to bottom, the bottom edge right to left, the left edge bottom to top."""
    u = np.linspace(0.0, width - 1.0, samples)
    v = np.linspace(0.0, height - 1.0, samples)
    return np.concatenate(
        [
            np.stack([u, np.zeros_like(u)], 1),
            np.stack([np.full_like(v, width - 1.0), v], 1),
            np.stack([u[::-1], np.full_like(u, height - 1.0)], 1),
            np.stack([np.zeros_like(v), v[::-1]], 1),
        ]
    )


def region_outline(mask: NDArray[np.bool_], points: int) -> F64:
    """Pixel centres (points, 2) evenly spaced along the outer border of the largest region of
    ``mask`` (H, W) (empty (0, 2) when nothing is set)."""
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return np.zeros((0, 2))
    outline = max(contours, key=cv2.contourArea).reshape(-1, 2).astype(np.float64)
    closed = np.vstack([outline, outline[:1]])
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(closed, axis=0).T))])
    at = np.linspace(0.0, along[-1], points, endpoint=False)
    return np.stack([np.interp(at, along, closed[:, 0]), np.interp(at, along, closed[:, 1])], axis=1)
