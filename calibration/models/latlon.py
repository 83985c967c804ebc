"""Transverse equirectangular ("lat-lon") projection: a rectified view, not a lens.

mrcal's ``LENSMODEL_LATLON`` convention: a point ``p`` maps to

    u = cx + fx · asin(x / |p|)        (azimuth: the angle out of the y-z plane, along x)
    v = cy + fy · atan2(y, z)          (elevation: the angle of the plane through the x axis)

so every row is a plane through the x axis and angles are evenly spaced along both image axes
(``fx``, ``fy`` in pixels per radian). With x along a stereo baseline every row of a rectified
pair is an epipolar plane, whatever the field of view: unlike a pinhole, the view may span more
than 180° across the baseline (``atan2`` covers the whole circle of elevations) and it keeps the
same angular resolution at the edges. The poles ``±x`` (looking along the baseline) are the only
singularity: points on the x axis are invalid.

Not one of :data:`calibration.models.MODELS` (nothing is calibrated with it); it has the same
``project``/``unproject`` surface with validity masks as every model.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from calibration.errors import ModelError
from calibration.models.base import CameraModel, Mask

__all__ = ["LatLonModel"]

F64 = NDArray[np.float64]


class LatLonModel(CameraModel):
    """``u = cx + fx·asin(x/|p|)``, ``v = cy + fy·atan2(y, z)`` (see the module doc).

    Unprojection: azimuth ``a = (u − cx)/fx`` in [−π/2, π/2], elevation ``e = (v − cy)/fy`` in
    [−π, π]; the ray is ``(sin a, cos a · sin e, cos a · cos e)``.
    """

    name = "latlon"
    param_names = ("fx", "fy", "cx", "cy")
    # Every direction has a pixel: the field limit is the image, not an angle off the z axis.
    _components_check_field = True

    def _setup(self) -> None:
        v = self._values
        self.fx, self.fy, self.cx, self.cy = v["fx"], v["fy"], v["cx"], v["cy"]
        if self.fx <= 0 or self.fy <= 0:
            raise ModelError(f"{self.name}: fx and fy must be positive")

    def _model_max_theta(self) -> float:
        return math.pi

    def _project(self, points: F64) -> tuple[F64, Mask]:
        u, v, ok = self._project_components(points[:, 0], points[:, 1], points[:, 2])
        return np.stack([u, v], axis=1), ok

    def _project_components(self, x: F64, y: F64, z: F64) -> tuple[F64, F64, Mask]:
        across = np.hypot(y, z)  # distance from the x axis
        ok = across > 0.0  # the poles have no elevation
        # asin(x/|p|) as atan2(x, across): the same angle, exact near ±90° where asin is not.
        u = np.arctan2(x, across)
        u *= self.fx
        u += self.cx
        v = np.arctan2(y, z)
        v *= self.fy
        v += self.cy
        return u, v, ok

    def _unproject(self, pixels: F64) -> tuple[F64, Mask]:
        az = (pixels[:, 0] - self.cx) / self.fx
        el = (pixels[:, 1] - self.cy) / self.fy
        ok = (np.abs(az) <= math.pi / 2.0) & (np.abs(el) <= math.pi)
        cos_az = np.cos(az)
        return np.stack([np.sin(az), cos_az * np.sin(el), cos_az * np.cos(el)], axis=1), ok

    def azimuths(self) -> F64:
        """Azimuth (W,) in radians of every column's pixel centre."""
        return (np.arange(self.width, dtype=np.float64) - self.cx) / self.fx

    def elevations(self) -> F64:
        """Elevation (H,) in radians of every row's pixel centre."""
        return (np.arange(self.height, dtype=np.float64) - self.cy) / self.fy
