"""Kannala-Brandt in OpenCV's ``cv2.fisheye`` convention:
``θd = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)``, ``u = fx θd x / r + cx``.

CamOdoCal's EquidistantCamera is the same model (mu, mv, u0, v0 = fx, fy, cx, cy;
k2..k5 = k1..k4). Unlike ``cv2.fisheye``, projection and unprojection stay valid past 90°,
up to the lens limit ``fov_deg / 2`` or where θd(θ) stops increasing, whichever comes first.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from calibration.models.base import Mask, register, smallest_positive_root
from calibration.models.radial import RadialThetaModel

__all__ = ["KannalaBrandtModel"]

F64 = NDArray[np.float64]


@register
class KannalaBrandtModel(RadialThetaModel):
    name = "kannala_brandt"
    param_names = ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")

    # Newton on θd(θ) stops when the step is below this (radians): ~1e-10 px at fx = 1000.
    THETA_TOL = 1e-13
    MAX_ITER = 60

    def _setup(self) -> None:
        self._setup_intrinsics()
        v = self._values
        self.k = (v["k1"], v["k2"], v["k3"], v["k4"])

    def _model_max_theta(self) -> float:
        k1, k2, k3, k4 = self.k
        # dθd/dθ = 1 + 3k1 θ² + 5k2 θ⁴ + 7k3 θ⁶ + 9k4 θ⁸, a polynomial in s = θ².
        s = smallest_positive_root([1.0, 3 * k1, 5 * k2, 7 * k3, 9 * k4])
        return min(math.sqrt(s), math.pi)

    def radius(self, theta: F64) -> F64:
        # θ(1 + t(k1 + t(k2 + t(k3 + t·k4)))), t = θ², Horner in place (two temporaries).
        k1, k2, k3, k4 = self.k
        t2 = theta * theta
        acc = t2 * k4
        for k in (k3, k2, k1):
            acc += k
            acc *= t2
        acc += 1.0
        acc *= theta
        return acc

    def radius_derivative(self, theta: F64) -> F64:
        k1, k2, k3, k4 = self.k
        t2 = theta * theta
        acc = t2 * 9
        acc *= k4
        for k in (7 * k3, 5 * k2, 3 * k1):
            acc += k
            acc *= t2
        acc += 1.0
        return acc

    def theta_from_radius(self, rd: F64) -> tuple[F64, Mask]:
        """Safeguarded Newton on [0, max_theta]: falls back to bisection when a step leaves
        the bracket; converged when the step is below ``THETA_TOL``."""
        hi_theta = self.max_theta
        inside = rd <= float(self.radius(np.array([hi_theta]))[0]) * (1.0 + 1e-12)
        lo = np.zeros_like(rd)
        hi = np.full_like(rd, hi_theta)
        theta = np.clip(rd, 0.0, hi_theta)
        converged = ~inside | (rd == 0.0)
        for _ in range(self.MAX_ITER):
            active = ~converged
            if not active.any():
                break
            f = self.radius(theta) - rd
            hi = np.where(active & (f > 0), theta, hi)
            lo = np.where(active & (f <= 0), theta, lo)
            d = self.radius_derivative(theta)
            newton = theta - f / np.where(d > 0, d, 1.0)
            # Strict bounds: a converged step lands exactly on the bracket end it came from.
            bad = (d <= 0) | (newton < lo) | (newton > hi) | ~np.isfinite(newton)
            step = np.where(bad, 0.5 * (lo + hi), newton)
            converged |= active & (np.abs(step - theta) <= self.THETA_TOL)
            theta = np.where(active, step, theta)
        return theta, inside & converged
