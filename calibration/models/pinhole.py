"""Pinhole camera with optional radial-tangential distortion: the VPC and reference cameras."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from calibration.errors import ModelError
from calibration.models.base import CameraModel, Mask, register
from calibration.models.radtan import RadTan

__all__ = ["PinholeModel"]

F64 = NDArray[np.float64]


@register
class PinholeModel(CameraModel):
    """``u = fx * x'' + cx`` with ``x''`` the radtan-distorted ``x/z`` (OpenCV convention).

    Valid for z > 0 and undistorted radii where the distortion stays one-to-one.
    """

    name = "pinhole"
    param_names = ("fx", "fy", "cx", "cy")
    optional_params: ClassVar[Mapping[str, float]] = {"k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0}

    def _setup(self) -> None:
        v = self._values
        self.fx, self.fy, self.cx, self.cy = v["fx"], v["fy"], v["cx"], v["cy"]
        if self.fx <= 0 or self.fy <= 0:
            raise ModelError(f"{self.name}: fx and fy must be positive")
        self.distortion = RadTan(v["k1"], v["k2"], v["p1"], v["p2"])

    @property
    def K(self) -> F64:
        """Intrinsic matrix (3, 3)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def _model_max_theta(self) -> float:
        return math.atan(self.distortion.r_max) if math.isfinite(self.distortion.r_max) else math.pi / 2

    def _project(self, points: F64) -> tuple[F64, Mask]:
        u, v, ok = self._project_components(points[:, 0], points[:, 1], points[:, 2])
        return np.stack([u, v], axis=1), ok

    def _project_components(self, x: F64, y: F64, z: F64) -> tuple[F64, F64, Mask]:
        ok = z > 0.0
        zs = np.where(ok, z, 1.0)
        xn = x / zs
        yn = np.divide(y, zs, out=zs)
        xd, yd, in_domain = self.distortion.distort_in_domain(xn, yn)
        ok &= in_domain
        xd *= self.fx
        xd += self.cx
        yd *= self.fy
        yd += self.cy
        return xd, yd, ok

    def _unproject(self, pixels: F64) -> tuple[F64, Mask]:
        xd = (pixels[:, 0] - self.cx) / self.fx
        yd = (pixels[:, 1] - self.cy) / self.fy
        x, y, ok = self.distortion.undistort(xd, yd)
        return np.stack([x, y, np.ones_like(x)], axis=1), ok
