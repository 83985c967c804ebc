"""Radial-tangential (Brown-Conrady, OpenCV order k1, k2, p1, p2) distortion on normalised
coordinates, shared by the pinhole and Mei models. Vectorised over (N,) arrays."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from calibration.models.base import smallest_positive_root

__all__ = ["RadTan"]

F64 = NDArray[np.float64]


class RadTan:
    """``m -> m(1 + k1 r^2 + k2 r^4) + [2 p1 x y + p2 (r^2 + 2x^2), 2 p2 x y + p1 (r^2 + 2y^2)]``."""

    def __init__(self, k1: float, k2: float, p1: float, p2: float) -> None:
        self.k1, self.k2, self.p1, self.p2 = k1, k2, p1, p2
        # The radial part r(1 + k1 r^2 + k2 r^4) stays invertible while its derivative
        # 1 + 3 k1 r^2 + 5 k2 r^4 is positive: that bounds the valid undistorted radius.
        self.r_max = math.sqrt(smallest_positive_root([1.0, 3.0 * k1, 5.0 * k2]))

    @property
    def is_identity(self) -> bool:
        return self.k1 == 0.0 and self.k2 == 0.0 and self.p1 == 0.0 and self.p2 == 0.0

    def distort(self, x: F64, y: F64) -> tuple[F64, F64]:
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + self.k2 * r2)
        xy = x * y
        xd = x * radial + 2.0 * self.p1 * xy + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + 2.0 * self.p2 * xy + self.p1 * (r2 + 2.0 * y * y)
        return xd, yd

    def jacobian(self, x: F64, y: F64) -> tuple[F64, F64, F64, F64]:
        """Entries (dxd/dx, dxd/dy, dyd/dx, dyd/dy), each (N,)."""
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + self.k2 * r2)
        g = 2.0 * (self.k1 + 2.0 * self.k2 * r2)  # d(radial)/d(r^2) * 2
        cross = x * y * g + 2.0 * self.p1 * x + 2.0 * self.p2 * y
        dxx = radial + x * x * g + 2.0 * self.p1 * y + 6.0 * self.p2 * x
        dyy = radial + y * y * g + 6.0 * self.p1 * y + 2.0 * self.p2 * x
        return dxx, cross, cross, dyy

    def in_domain(self, x: F64, y: F64) -> NDArray[np.bool_]:
        """Undistorted points where the distortion is one-to-one (radius below ``r_max``)."""
        r = np.sqrt(x * x + y * y)  # not np.hypot: ~8x slower, and no overflow is possible here
        dxx, dxy, dyx, dyy = self.jacobian(x, y)
        return (r < self.r_max) & (dxx * dyy - dxy * dyx > 0.0)

    def distort_in_domain(self, x: F64, y: F64) -> tuple[F64, F64, NDArray[np.bool_]]:
        """``distort(x, y)`` and ``in_domain(x, y)`` in one pass (shared terms, few temporaries):
        the projection hot path of the Mei and pinhole models."""
        if self.is_identity:
            return x.copy(), y.copy(), np.ones(x.shape, dtype=bool)
        k1, k2, p1, p2 = self.k1, self.k2, self.p1, self.p2
        xx = x * x
        yy = y * y
        xy = x * y
        r2 = xx + yy
        ok = r2 < self.r_max * self.r_max if np.isfinite(self.r_max) else np.ones(x.shape, dtype=bool)
        radial = r2 * k2
        radial += k1  # k1 + k2 r²
        g = r2 * (4.0 * k2)
        g += 2.0 * k1  # d(radial)/d(r²) · 2
        radial *= r2
        radial += 1.0
        # Jacobian (see jacobian()): dxx, dyy, and cross = dxy = dyx.
        cross = xy * g
        cross += (2.0 * p1) * x
        cross += (2.0 * p2) * y
        dxx = xx * g
        dxx += radial
        dxx += (2.0 * p1) * y
        dxx += (6.0 * p2) * x
        dyy = yy * g
        dyy += radial
        dyy += (6.0 * p1) * y
        dyy += (2.0 * p2) * x
        dxx *= dyy
        cross *= cross
        ok &= dxx > cross
        # distort(): x·radial + 2p1·xy + p2(r² + 2x²), y·radial + 2p2·xy + p1(r² + 2y²).
        xd = x * radial
        xd += (2.0 * p1) * xy
        xx *= 2.0
        xx += r2
        xx *= p2
        xd += xx
        yd = y * radial
        yd += (2.0 * p2) * xy
        yy *= 2.0
        yy += r2
        yy *= p1
        yd += yy
        return xd, yd, ok

    def undistort(
        self, xd: F64, yd: F64, tol: float = 1e-14, max_iter: int = 50
    ) -> tuple[F64, F64, NDArray[np.bool_]]:
        """Invert :meth:`distort` by Newton's method until the residual is below ``tol``.

        Returns (x, y, converged); points that do not converge, or converge outside the
        invertible domain, are reported False.
        """
        x, y = xd.copy(), yd.copy()
        if self.is_identity:
            return x, y, np.ones(x.shape, dtype=bool)
        done = np.zeros(x.shape, dtype=bool)
        scale = np.maximum(1.0, np.hypot(xd, yd))
        for _ in range(max_iter):
            fx, fy = self.distort(x, y)
            ex, ey = fx - xd, fy - yd
            done = np.hypot(ex, ey) <= tol * scale
            if done.all():
                break
            a, b, c, d = self.jacobian(x, y)
            det = a * d - b * c
            safe = np.abs(det) > 1e-300
            det = np.where(safe, det, 1.0)
            dx = (d * ex - b * ey) / det
            dy = (-c * ex + a * ey) / det
            step = ~done & safe
            x = np.where(step, x - dx, x)
            y = np.where(step, y - dy, y)
            # Keep diverging points finite; they are reported as not converged below.
            bad = ~np.isfinite(x) | ~np.isfinite(y)
            x = np.where(bad, 0.0, x)
            y = np.where(bad, 0.0, y)
        return x, y, done & self.in_domain(x, y)
