"""Double Sphere model (Usenko, Demmel, Cremers 2018; basalt-headers ``DoubleSphereCamera``,
Kalibr ``ds``), closed form both ways. Parameters fx, fy, cx, cy, ξ ∈ (−1, 1], α ∈ [0, 1]::

    d1 = |(x, y, z)|,  k = ξ·d1 + z,  d2 = |(x, y, k)|
    u  = fx·x / (α·d2 + (1 − α)·k) + cx,   v = fy·y / (α·d2 + (1 − α)·k) + cy

Unprojection, with m = ((u − cx)/fx, (v − cy)/fy) and r² = |m|²::

    mz  = (1 − α² r²) / (α √(1 − (2α − 1) r²) + 1 − α)
    ray = (mz ξ + √(mz² + (1 − ξ²) r²)) / (mz² + r²) · (mx, my, mz) − (0, 0, ξ)

Published validity: projection for ``z > −w2·d1`` with ``w1 = α/(1 − α)`` (α ≤ 0.5) or
``(1 − α)/α`` (α > 0.5) and ``w2 = (w1 + ξ) / √(2 w1 ξ + ξ² + 1)``; unprojection everywhere for
α ≤ 0.5, else for ``r² ≤ 1/(2α − 1)``. ``max_theta`` is the tighter of the two limits as an angle,
so both directions agree.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from calibration.errors import ModelError
from calibration.models.base import CameraModel, Mask, pixels_from_ratio, register

__all__ = ["DoubleSphereModel"]

F64 = NDArray[np.float64]


@register
class DoubleSphereModel(CameraModel):
    name = "double_sphere"
    param_names = ("fx", "fy", "cx", "cy", "xi", "alpha")

    def _setup(self) -> None:
        v = self._values
        self.fx, self.fy, self.cx, self.cy = v["fx"], v["fy"], v["cx"], v["cy"]
        self.xi, self.alpha = v["xi"], v["alpha"]
        if self.fx <= 0 or self.fy <= 0:
            raise ModelError(f"{self.name}: fx and fy must be positive")
        if not -1.0 < self.xi <= 1.0:
            raise ModelError(f"{self.name}: xi must be in (-1, 1], got {self.xi}")
        if not 0.0 <= self.alpha <= 1.0:
            raise ModelError(f"{self.name}: alpha must be in [0, 1], got {self.alpha}")
        a, xi = self.alpha, self.xi
        w1 = (1.0 - a) / a if a > 0.5 else a / (1.0 - a)
        self.w2 = (w1 + xi) / math.sqrt(2.0 * w1 * xi + xi * xi + 1.0)
        # Largest r² of the unprojection domain (inf when alpha <= 0.5).
        self.r2_max = 1.0 / (2.0 * a - 1.0) if a > 0.5 else math.inf

    def _model_max_theta(self) -> float:
        theta = math.acos(max(-1.0, min(1.0, -self.w2)))
        if math.isfinite(self.r2_max):
            ray, _ = self._unproject_normalised(np.array([math.sqrt(self.r2_max)]), np.array([0.0]))
            theta = min(theta, math.atan2(float(ray[0, 0]), float(ray[0, 2])))
        return theta

    def _project(self, points: F64) -> tuple[F64, Mask]:
        u, v, ok = self._project_components(points[:, 0], points[:, 1], points[:, 2])
        return np.stack([u, v], axis=1), ok

    def _project_components(self, x: F64, y: F64, z: F64) -> tuple[F64, F64, Mask]:
        r2 = x * x
        r2 += y * y
        d1 = z * z
        d1 += r2
        np.sqrt(d1, out=d1)
        k = self.xi * d1
        k += z
        d2 = k * k
        d2 += r2
        np.sqrt(d2, out=d2)
        den = d2
        den *= self.alpha
        den += (1.0 - self.alpha) * k
        ok = z > -self.w2 * d1
        ok &= den > 0.0
        # inf/garbage where den <= 0: masked by ok
        u, v = pixels_from_ratio(x, y, den, self.fx, self.fy, self.cx, self.cy)
        return u, v, ok

    def _unproject_normalised(self, mx: F64, my: F64) -> tuple[F64, Mask]:
        a, xi = self.alpha, self.xi
        r2 = mx * mx + my * my
        ok = r2 <= self.r2_max
        root = np.sqrt(np.maximum(1.0 - (2.0 * a - 1.0) * r2, 0.0))
        mz = (1.0 - a * a * r2) / (a * root + 1.0 - a)
        k = (mz * xi + np.sqrt(np.maximum(mz * mz + (1.0 - xi * xi) * r2, 0.0))) / (mz * mz + r2)
        return np.stack([k * mx, k * my, k * mz - xi], axis=1), ok

    def _unproject(self, pixels: F64) -> tuple[F64, Mask]:
        mx = (pixels[:, 0] - self.cx) / self.fx
        my = (pixels[:, 1] - self.cy) / self.fy
        return self._unproject_normalised(mx, my)
