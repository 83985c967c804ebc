"""Scaramuzza's polynomial omnidirectional model (OCamCalib, MATLAB ``fisheyeIntrinsics``), in our
z-forward camera frame. Parameters: ``poly`` (list a0, a1, a2, ... with a0 > 0), optional
``invpol`` (list; fitted when absent), cx, cy (distortion centre, pixels), c, d, e (stretch).

Back-projection is closed form (OCamCalib ``cam2world``)::

    [u'; v'] = A⁻¹ ([u; v] − [cx; cy]),   A = [[c, d], [e, 1]] on (u, v) = (column, row)
    ρ = |(u', v')|,   ray = (u', v', a0 + a1 ρ + a2 ρ² + ...)      (every coefficient of poly)

This is MATLAB's StretchMatrix convention. OCamCalib's ``calib_results.txt`` works in (row,
column) with z pointing backwards (a0 < 0); its loader converts it.

Projection (OCamCalib ``world2cam``): ``invpol`` gives ρ as a polynomial (ascending) in
ψ = θ − π/2, θ the angle between the ray and the optical axis: exactly OCamCalib's
``theta = atan(z / |xy|)`` with its backward z, so a file's invpol loads unchanged. That ρ is then
polished by safeguarded Newton on the exact poly, ``poly(ρ)·sin θ − ρ·cos θ = 0``, to a tolerance
(not converged -> invalid), so ``project(unproject(p)) = p`` to far below 1e-6 px. Without
``invpol`` one is fitted at construction by least squares, raising the degree until the largest
error over the valid field is at most :attr:`ScaramuzzaModel.INVPOL_TOLERANCE_PX`, as OCamCalib does.

Validity: ρ from 0 up to where θ(ρ) = atan2(ρ, poly(ρ)) stops increasing
(``poly(ρ) − ρ·poly'(ρ) = 0``) or the largest ρ inside the image (at a corner), whichever is first.

Parameter vector (:attr:`params`): ``poly[0] .. poly[n-1], cx, cy, c, d, e``; ``invpol`` is derived
and refitted by :meth:`with_params` whenever the vector changes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from calibration.errors import ModelError
from calibration.models.base import CameraModel, Mask, register, smallest_positive_root

__all__ = ["ScaramuzzaModel"]

F64 = NDArray[np.float64]


def _horner(coeffs: Sequence[float], x: F64) -> F64:
    """Σ coeffs[i]·x^i for (N,) x."""
    out = np.zeros_like(x)
    for c in reversed(coeffs):
        out = out * x + c
    return out


@register
class ScaramuzzaModel(CameraModel):
    name = "scaramuzza"
    param_names = ("poly", "cx", "cy", "c", "d", "e")
    optional_params: ClassVar[Mapping[str, float | tuple[float, ...]]] = {"invpol": ()}
    list_params = ("poly", "invpol")
    derived_params = ("invpol",)

    # Largest error (pixels of ρ) of a fitted invpol over the valid field.
    INVPOL_TOLERANCE_PX = 0.01
    INVPOL_MAX_DEGREE = 30
    # Newton on ρ stops when the step is below this relative size (~1e-9 px at ρ = 1000).
    RHO_RTOL = 1e-12
    MAX_ITER = 80

    def _setup(self) -> None:
        poly = self._lists["poly"]
        v = self._values
        if len(poly) < 1:
            raise ModelError(f"{self.name}: parameter poly must have at least one coefficient")
        if poly[0] <= 0.0:
            raise ModelError(
                f"{self.name}: poly[0] (a0) must be > 0 (z forward); OCamCalib files store a0 < 0 "
                f"with z backwards, got {poly[0]}"
            )
        self.poly = poly
        self.dpoly = tuple(i * a for i, a in enumerate(poly))[1:]
        self.cx, self.cy, self.c, self.d, self.e = v["cx"], v["cy"], v["c"], v["d"], v["e"]
        det = self.c - self.d * self.e
        if det <= 0.0:
            raise ModelError(f"{self.name}: stretch matrix determinant c - d*e must be > 0, got {det}")
        self.A = np.array([[self.c, self.d], [self.e, 1.0]])
        self.A_inv = np.linalg.inv(self.A)
        w, h = self.width, self.height
        corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]])
        rho_corner = float(np.linalg.norm(self._undistorted(corners), axis=1).max())
        # dθ/dρ ∝ poly(ρ) − ρ·poly'(ρ) = Σ (1 − i) a_i ρ^i: θ increases until its first root.
        rho_turn = smallest_positive_root([(1 - i) * a for i, a in enumerate(poly)])
        self.rho_max = min(rho_corner, rho_turn)
        self.theta_max_model = math.atan2(self.rho_max, float(_horner(poly, np.array([self.rho_max]))[0]))
        # Largest error of a fitted invpol (pixels); None when the invpol was given.
        self.invpol_error_px: float | None = None
        if not self._lists["invpol"]:
            self._lists["invpol"] = self._fit_invpol()
        self.invpol = self._lists["invpol"]

    def _undistorted(self, pixels: F64) -> F64:
        """(N, 2) pixels -> (N, 2) (u', v') = A⁻¹ (p − centre)."""
        return (pixels - np.array([self.cx, self.cy])) @ self.A_inv.T

    def theta_of_rho(self, rho: F64) -> F64:
        """Angle off the optical axis θ(ρ) = atan2(ρ, poly(ρ)) for (N,) radii."""
        return np.arctan2(rho, _horner(self.poly, rho))

    def _fit_invpol(self) -> tuple[float, ...]:
        """Least-squares ρ(ψ) polynomial of the lowest degree within INVPOL_TOLERANCE_PX."""
        rho = np.linspace(0.0, self.rho_max, 1001)
        psi = self.theta_of_rho(rho) - math.pi / 2
        # Powers of t = ψ / max|ψ| (columns of order one), orthonormalised one degree at a time
        # (Gram-Schmidt, twice): the fit of degree k is R[:k+1, :k+1]⁻¹ (Qᵀρ)[:k+1]. Cheaper than
        # a LAPACK least squares per degree, whose thread start-up dominates at this size.
        scale = float(np.abs(psi).max())
        t = psi / scale
        size = self.INVPOL_MAX_DEGREE + 1
        q = np.empty((t.size, size))
        r = np.zeros((size, size))
        qt_rho = np.zeros(size)
        column = np.ones_like(t)
        best_err, best = math.inf, np.zeros(1)
        stalled = 0
        for j in range(size):
            v = column.copy()
            for _ in range(2):
                c = q[:, :j].T @ v
                r[:j, j] += c
                v -= q[:, :j] @ c
            r[j, j] = float(np.linalg.norm(v))
            q[:, j] = v / r[j, j]
            qt_rho[j] = float(q[:, j] @ rho)
            column = column * t
            if j == 0:
                continue
            coeffs = np.linalg.solve(r[: j + 1, : j + 1], qt_rho[: j + 1]) / scale ** np.arange(j + 1)
            err = float(np.abs(_horner(tuple(coeffs), psi) - rho).max())
            stalled = stalled + 1 if err > 0.99 * best_err else 0
            if err < best_err:
                best_err, best = err, coeffs
            # Stop at the tolerance, or once more terms stop helping (ρ(ψ) too steep near a
            # turning point): the invpol only seeds Newton, so projection stays exact anyway.
            if err <= self.INVPOL_TOLERANCE_PX or stalled >= 5:
                break
        self.invpol_error_px = best_err
        return tuple(float(x) for x in best)

    def _model_max_theta(self) -> float:
        return self.theta_max_model

    def _project(self, points: F64) -> tuple[F64, Mask]:
        x, y, z = points[:, 0], points[:, 1], points[:, 2]
        r = np.hypot(x, y)
        theta = np.arctan2(r, z)
        sin_t, cos_t = np.sin(theta), np.cos(theta)
        inside = np.isfinite(theta) & (theta <= self.theta_max_model * (1.0 + 1e-12))
        hi_rho = self.rho_max
        lo = np.zeros_like(r)
        hi = np.full_like(r, hi_rho)
        seed = _horner(self.invpol, np.where(inside, theta, 0.0) - math.pi / 2)
        rho = np.clip(np.where(np.isfinite(seed), seed, 0.5 * hi_rho), 0.0, hi_rho)
        converged = ~inside
        for _ in range(self.MAX_ITER):
            active = ~converged
            if not active.any():
                break
            # f(ρ) = |ray(ρ)|·sin(θ − θ(ρ)): positive below the root, negative above.
            f = _horner(self.poly, rho) * sin_t - rho * cos_t
            fp = _horner(self.dpoly, rho) * sin_t - cos_t
            lo = np.where(active & (f >= 0), rho, lo)
            hi = np.where(active & (f < 0), rho, hi)
            newton = rho - f / np.where(fp < 0, fp, -1.0)
            bad = (fp >= 0) | (newton < lo) | (newton > hi) | ~np.isfinite(newton)
            step = np.where(bad, 0.5 * (lo + hi), newton)
            converged |= active & (np.abs(step - rho) <= self.RHO_RTOL * np.maximum(1.0, rho))
            rho = np.where(active, step, rho)
        ok = inside & converged & ((r > 0.0) | (z > 0.0))
        scale = np.divide(rho, r, out=np.zeros_like(r), where=r > 0.0)
        undist = np.stack([scale * x, scale * y], axis=1)
        return undist @ self.A.T + np.array([self.cx, self.cy]), ok

    def _unproject(self, pixels: F64) -> tuple[F64, Mask]:
        undist = self._undistorted(pixels)
        rho = np.hypot(undist[:, 0], undist[:, 1])
        ok = rho <= self.rho_max * (1.0 + 1e-12)
        z = _horner(self.poly, rho)
        return np.stack([undist[:, 0], undist[:, 1], z], axis=1), ok
