"""Central models radially symmetric in the angle θ off the optical axis: ``rd = g(θ)`` and
``u = fx * rd * x / r + cx`` (r = |(x, y)|). Equidistant and Kannala-Brandt are of this family."""

from __future__ import annotations

from abc import abstractmethod

import numpy as np
from numpy.typing import NDArray

from calibration.errors import ModelError
from calibration.models.base import CameraModel, Mask

__all__ = ["RadialThetaModel"]

F64 = NDArray[np.float64]


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

    def _project(self, points: F64) -> tuple[F64, Mask]:
        x, y, z = points[:, 0], points[:, 1], points[:, 2]
        r = np.hypot(x, y)
        theta = np.arctan2(r, z)
        # On the axis the direction x/r is undefined but irrelevant in front; behind, it is a
        # single point with no image.
        ok = (r > 0.0) | (z > 0.0)
        scale = np.divide(self.radius(theta), r, out=np.zeros_like(r), where=r > 0.0)
        return np.stack([self.fx * scale * x + self.cx, self.fy * scale * y + self.cy], axis=1), ok

    def _unproject(self, pixels: F64) -> tuple[F64, Mask]:
        mx = (pixels[:, 0] - self.cx) / self.fx
        my = (pixels[:, 1] - self.cy) / self.fy
        rd = np.hypot(mx, my)
        theta, ok = self.theta_from_radius(rd)
        s = np.divide(np.sin(theta), rd, out=np.ones_like(rd), where=rd > 0.0)
        return np.stack([s * mx, s * my, np.cos(theta)], axis=1), ok
