"""Mei's unified omnidirectional model (sphere + radial-tangential distortion).

Convention of OpenCV contrib ``cv::omnidir`` and CamOdoCal's ``CataCamera`` (gamma1, gamma2, u0,
v0 = fx, fy, cx, cy), with OpenCV's optional skew ``s``::

    Ps = P / |P|                                  (point on the unit sphere)
    m  = (Xs, Ys) / (Zs + ξ)                      (projection from (0, 0, -ξ))
    md = radtan(m; k1, k2, p1, p2)                (OpenCV order, :class:`RadTan`)
    u  = fx·md_x + s·md_y + cx,   v = fy·md_y + cy

Unprojection: Newton undistortion of the radtan part to a tolerance (non-convergence, or a result
outside the invertible region, is invalid), then the closed-form lift to the sphere
``λ = (ξ + √(1 + (1 − ξ²)ρ²)) / (1 + ρ²)``, ``Ps = (λ m_x, λ m_y, λ − ξ)`` with ρ = |m|.

Domain (basalt-headers ``UnifiedCamera``, whose α = ξ / (1 + ξ)): the projection is one-to-one for
``Zs > −min(ξ, 1/ξ)``. For ξ ≤ 1 this is where ``Zs + ξ > 0``; for ξ > 1 the projection centre lies
outside the sphere and only the far cap beyond the tangent circle ``Zs = −1/ξ`` is one-to-one; its
image is the disc ``ρ² ≤ 1/(ξ² − 1)`` where the lift's square root is real. Radtan adds its own
limit (undistorted radius below :attr:`RadTan.r_max` with a positive Jacobian); project and
unproject use the same conditions, so round trips hold wherever either says valid.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from calibration.errors import ModelError
from calibration.models.base import CameraModel, Mask, register
from calibration.models.radtan import RadTan

__all__ = ["MeiModel"]

F64 = NDArray[np.float64]
_TINY = 1e-300


@register
class MeiModel(CameraModel):
    """Unified (Mei) model: parameters xi, k1, k2, p1, p2, fx, fy, cx, cy and optional skew s."""

    name = "mei"
    param_names = ("xi", "k1", "k2", "p1", "p2", "fx", "fy", "cx", "cy")
    optional_params: ClassVar[Mapping[str, float]] = {"s": 0.0}

    def _setup(self) -> None:
        v = self._values
        self.xi = v["xi"]
        self.fx, self.fy, self.cx, self.cy, self.s = v["fx"], v["fy"], v["cx"], v["cy"], v["s"]
        if self.fx <= 0 or self.fy <= 0:
            raise ModelError(f"{self.name}: fx and fy must be positive")
        if self.xi < 0:
            raise ModelError(f"{self.name}: xi must be >= 0, got {self.xi}")
        self.distortion = RadTan(v["k1"], v["k2"], v["p1"], v["p2"])
        # Lowest Zs (cosine off axis) of the one-to-one part of the sphere.
        self.zs_min = -min(self.xi, 1.0 / self.xi) if self.xi > 0 else 0.0

    def lift(self, mx: F64, my: F64) -> tuple[F64, Mask]:
        """Undistorted normalised points (N,) each -> points on the unit sphere (N, 3), ok (N,)."""
        r2 = mx * mx + my * my
        disc = 1.0 + (1.0 - self.xi * self.xi) * r2
        ok = disc >= 0.0
        lam = (self.xi + np.sqrt(np.where(ok, disc, 0.0))) / (1.0 + r2)
        return np.stack([lam * mx, lam * my, lam - self.xi], axis=1), ok

    def _model_max_theta(self) -> float:
        theta = math.acos(self.zs_min)
        r_max = self.distortion.r_max
        if math.isfinite(r_max):
            sphere, ok = self.lift(np.array([r_max]), np.array([0.0]))
            if ok[0]:
                theta = min(theta, math.acos(max(-1.0, min(1.0, float(sphere[0, 2])))))
        return theta

    def _project(self, points: F64) -> tuple[F64, Mask]:
        u, v, ok = self._project_components(points[:, 0], points[:, 1], points[:, 2])
        return np.stack([u, v], axis=1), ok

    def _project_components(self, x: F64, y: F64, z: F64) -> tuple[F64, F64, Mask]:
        norm = x * x
        norm += y * y
        norm += z * z
        np.sqrt(norm, out=norm)
        np.maximum(norm, _TINY, out=norm)  # the zero point is invalid (base class) but finite
        zs = z / norm
        ok = zs >= self.zs_min
        den = zs
        den += self.xi
        ok &= den > 0.0
        den *= norm  # m = (x, y) / |P| / (Zs + ξ)
        mx = x / den
        my = np.divide(y, den, out=den)
        xd, yd, in_domain = self.distortion.distort_in_domain(mx, my)
        ok &= in_domain
        u = xd * self.fx
        u += self.s * yd
        u += self.cx
        yd *= self.fy
        yd += self.cy
        return u, yd, ok

    def _unproject(self, pixels: F64) -> tuple[F64, Mask]:
        yd = (pixels[:, 1] - self.cy) / self.fy
        xd = (pixels[:, 0] - self.cx - self.s * yd) / self.fx
        mx, my, converged = self.distortion.undistort(xd, yd)
        sphere, ok = self.lift(mx, my)
        return sphere, ok & converged
