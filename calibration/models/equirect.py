"""Equirectangular projection about a vertical axis: a panorama, not a lens.

mrcal's ``LENSMODEL_LONLAT`` convention: a point ``p`` maps to

    u = cx + fx · atan2(x, z)          (longitude: the azimuth about the y axis, the vertical)
    v = cy + fy · asin(y / |p|)        (latitude: the angle out of the x-z plane, y down)

so columns are half-planes through the y axis and angles are evenly spaced along both image axes
(``fx``, ``fy`` in pixels per radian): 360° of azimuth across, 180° of elevation down, the sphere
in one image. The poles ``±y`` (straight up or down) are the only singularity: points on the y
axis are invalid. It is :class:`~calibration.models.latlon.LatLonModel` with the roles of x and
y exchanged (that one turns about the baseline, this one about the vertical).

Not one of :data:`calibration.models.MODELS` (nothing is calibrated with it); it has the same
``project``/``unproject`` surface with validity masks as every model.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from calibration.errors import ModelError
from calibration.models.base import CameraModel, Mask

__all__ = ["EquirectModel"]

F64 = NDArray[np.float64]


class EquirectModel(CameraModel):
    """``u = cx + fx·atan2(x, z)``, ``v = cy + fy·asin(y/|p|)`` (see the module doc).

    Unprojection: longitude ``a = (u − cx)/fx`` in [−π, π], latitude ``e = (v − cy)/fy`` in
    [−π/2, π/2]; the ray is ``(cos e · sin a, sin e, cos e · cos a)``.
    """

    name = "equirect"
    param_names = ("fx", "fy", "cx", "cy")
    # Every direction has a pixel: the field limit is the image, not an angle off the z axis.
    _components_check_field = True

    def _setup(self) -> None:
        v = self._values
        self.fx, self.fy, self.cx, self.cy = v["fx"], v["fy"], v["cx"], v["cy"]
        if self.fx <= 0 or self.fy <= 0:
            raise ModelError(f"{self.name}: fx and fy must be positive")

    @classmethod
    def whole_sphere(cls, px_per_deg: float) -> EquirectModel:
        """360° × 180° at ``px_per_deg`` both ways: longitude −180° at the left edge, latitude −90°
        (straight up, y down) at the top edge, pixel centres half a pixel inside."""
        width, height = round(360.0 * px_per_deg), round(180.0 * px_per_deg)
        if width < 2 or height < 2:
            raise ModelError(f"equirect: {px_per_deg} px/deg gives no image")
        f = width / (2.0 * math.pi)  # exactly 360° across, whatever the rounding
        return cls(width, height, fx=f, fy=f, cx=-0.5 + math.pi * f, cy=-0.5 + math.pi / 2.0 * f)

    def _model_max_theta(self) -> float:
        return math.pi

    def _project(self, points: F64) -> tuple[F64, Mask]:
        u, v, ok = self._project_components(points[:, 0], points[:, 1], points[:, 2])
        return np.stack([u, v], axis=1), ok

    def _project_components(self, x: F64, y: F64, z: F64) -> tuple[F64, F64, Mask]:
        across = np.hypot(x, z)  # distance from the y axis
        ok = across > 0.0  # the poles have no longitude
        u = np.arctan2(x, z)
        u *= self.fx
        u += self.cx
        # asin(y/|p|) as atan2(y, across): the same angle, exact near ±90° where asin is not.
        v = np.arctan2(y, across)
        v *= self.fy
        v += self.cy
        return u, v, ok

    def _unproject(self, pixels: F64) -> tuple[F64, Mask]:
        lon = (pixels[:, 0] - self.cx) / self.fx
        lat = (pixels[:, 1] - self.cy) / self.fy
        ok = (np.abs(lon) <= math.pi) & (np.abs(lat) <= math.pi / 2.0)
        cos_lat = np.cos(lat)
        return np.stack([cos_lat * np.sin(lon), np.sin(lat), cos_lat * np.cos(lon)], axis=1), ok
