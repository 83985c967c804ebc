"""Central models radially symmetric in the angle θ off the optical axis: ``rd = g(θ)`` and
``u = fx * rd * x / r + cx`` (r = |(x, y)|). Equidistant and Kannala-Brandt are of this family."""

from __future__ import annotations

from abc import abstractmethod

import numpy as np
from numpy.typing import NDArray

from calibration.errors import ModelError
from calibration.models.base import _THETA_SLACK, CameraModel, Mask

__all__ = ["RadialThetaModel"]

F64 = NDArray[np.float64]
_TINY = 1e-300


class RadialThetaModel(CameraModel):
    """Base for ``rd = g(θ)`` models with parameters fx, fy, cx, cy (+ the shape of g)."""

    def _setup_intrinsics(self) -> None:
        v = self._values
        self.fx, self.fy, self.cx, self.cy = v["fx"], v["fy"], v["cx"], v["cy"]
        if self.fx <= 0 or self.fy <= 0:
            raise ModelError(f"{self.name}: fx and fy must be positive")

    @abstractmethod
    def radius(self, theta: F64) -> F64:
        """g(θ): normalised image radius for angle θ (N,)."""

    @abstractmethod
    def theta_from_radius(self, rd: F64) -> tuple[F64, Mask]:
        """Inverse of g on [0, max_theta]: (θ, ok) for normalised radii (N,)."""

    _components_check_field = True

    def _project(self, points: F64) -> tuple[F64, Mask]:
        u, v, ok = self._project_components(points[:, 0], points[:, 1], points[:, 2])
        return np.stack([u, v], axis=1), ok

    def _project_components(self, x: F64, y: F64, z: F64) -> tuple[F64, F64, Mask]:
        # Written in place: a LUT build runs this on every VPC pixel (rig.lut).
        r = x * x
        r += y * y
        np.sqrt(r, out=r)  # not np.hypot: ~8x slower, and no overflow is possible here
        theta = np.arctan2(r, z)
        ok = theta <= self.max_theta * (1.0 + _THETA_SLACK)
        # On the axis the direction x/r is undefined but irrelevant in front; behind, it is a
        # single point with no image.
        ok &= (r > 0.0) | (z > 0.0)
        scale = self.radius(theta)
        # g(0) = 0: on the axis scale = 0/tiny = 0 puts the point on the principal point.
        scale /= np.maximum(r, _TINY, out=r)
        u = x * scale
        u *= self.fx
        u += self.cx
        scale *= y
        scale *= self.fy
        scale += self.cy
        return u, scale, ok

    def _unproject(self, pixels: F64) -> tuple[F64, Mask]:
        mx = (pixels[:, 0] - self.cx) / self.fx
        my = (pixels[:, 1] - self.cy) / self.fy
        rd = np.hypot(mx, my)
        theta, ok = self.theta_from_radius(rd)
        s = np.divide(np.sin(theta), rd, out=np.ones_like(rd), where=rd > 0.0)
        return np.stack([s * mx, s * my, np.cos(theta)], axis=1), ok
