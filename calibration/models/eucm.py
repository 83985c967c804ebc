"""Extended Unified Camera Model (Khomutenko et al. 2016; basalt-headers
``ExtendedUnifiedCamera``, Kalibr ``eucm``), closed form both ways. Parameters fx, fy, cx, cy,
α ∈ [0, 1], β > 0::

    d = √(β (x² + y²) + z²)
    u = fx·x / (α d + (1 − α) z) + cx,   v = fy·y / (α d + (1 − α) z) + cy

Unprojection, with m = ((u − cx)/fx, (v − cy)/fy) and r² = |m|²::

    mz  = (1 − β α² r²) / (α √(1 − (2α − 1) β r²) + 1 − α),   ray = (mx, my, mz)

Published validity: projection for ``z > −w·d`` with ``w = α/(1 − α)`` (α ≤ 0.5) or
``(1 − α)/α`` (α > 0.5); unprojection everywhere for α ≤ 0.5, else for ``r² ≤ 1/(β(2α − 1))``.
β = 1 is the plain unified model (UCM). ``max_theta`` is the tighter of the two limits.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from calibration.errors import ModelError
from calibration.models.base import CameraModel, Mask, pixels_from_ratio, register

__all__ = ["EucmModel"]

F64 = NDArray[np.float64]


@register
class EucmModel(CameraModel):
    name = "eucm"
    param_names = ("fx", "fy", "cx", "cy", "alpha", "beta")

    def _setup(self) -> None:
        v = self._values
        self.fx, self.fy, self.cx, self.cy = v["fx"], v["fy"], v["cx"], v["cy"]
        self.alpha, self.beta = v["alpha"], v["beta"]
        if self.fx <= 0 or self.fy <= 0:
            raise ModelError(f"{self.name}: fx and fy must be positive")
        if not 0.0 <= self.alpha <= 1.0:
            raise ModelError(f"{self.name}: alpha must be in [0, 1], got {self.alpha}")
        if self.beta <= 0.0:
            raise ModelError(f"{self.name}: beta must be > 0, got {self.beta}")
        a = self.alpha
        self.w = (1.0 - a) / a if a > 0.5 else a / (1.0 - a)
        self.r2_max = 1.0 / (self.beta * (2.0 * a - 1.0)) if a > 0.5 else math.inf

    def _model_max_theta(self) -> float:
        # z = −w·d on the unit sphere: cot²θ = w²β / (1 − w²) with θ past 90° (no limit at w = 1).
        w = self.w
        theta = math.pi if w >= 1.0 else math.pi / 2 + math.atan(w * math.sqrt(self.beta / (1.0 - w * w)))
        if math.isfinite(self.r2_max):
            ray, _ = self._unproject_normalised(np.array([math.sqrt(self.r2_max)]), np.array([0.0]))
            theta = min(theta, math.atan2(float(ray[0, 0]), float(ray[0, 2])))
        return theta

    def _project(self, points: F64) -> tuple[F64, Mask]:
        u, v, ok = self._project_components(points[:, 0], points[:, 1], points[:, 2])
        return np.stack([u, v], axis=1), ok

    def _project_components(self, x: F64, y: F64, z: F64) -> tuple[F64, F64, Mask]:
        d = x * x
        d += y * y
        d *= self.beta
        d += z * z
        np.sqrt(d, out=d)
        ok = z > -self.w * d
        den = d
        den *= self.alpha
        den += (1.0 - self.alpha) * z
        ok &= den > 0.0
        # inf/garbage where den <= 0: masked by ok
        u, v = pixels_from_ratio(x, y, den, self.fx, self.fy, self.cx, self.cy)
        return u, v, ok

    def _unproject_normalised(self, mx: F64, my: F64) -> tuple[F64, Mask]:
        a, b = self.alpha, self.beta
        r2 = mx * mx + my * my
        ok = r2 <= self.r2_max
        root = np.sqrt(np.maximum(1.0 - (2.0 * a - 1.0) * b * r2, 0.0))
        mz = (1.0 - b * a * a * r2) / (a * root + 1.0 - a)
        return np.stack([mx, my, mz], axis=1), ok

    def _unproject(self, pixels: F64) -> tuple[F64, Mask]:
        mx = (pixels[:, 0] - self.cx) / self.fx
        my = (pixels[:, 1] - self.cy) / self.fy
        return self._unproject_normalised(mx, my)
