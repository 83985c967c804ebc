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

Parameter ranges (ModelError outside, generous: they catch nonsense such as a centre at 1e200 px,
which would otherwise overflow): the centre within an image size of the image, |c|, |d|, |e| ≤ 10
with ``c − d·e ≥ 0.01``, poly and poly' below 1e300 over the valid ρ, and a field of at least
0.01° off axis.

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
    """Σ coeffs[i]·x^i for (N,) x (in place: one temporary)."""
    if not coeffs:
        return np.zeros_like(x)
    out = np.full_like(x, coeffs[-1])
    for c in reversed(coeffs[:-1]):
        out *= x
        out += c
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
    # Seeds from a table of the exact ρ(θ) for calls of at least this many points (see _seed_rho).
    SEED_TABLE_MIN_POINTS = 4096
    SEED_TABLE_NODES = 4096
    # Generous sanity bounds (real files: c ≈ 1, |d|, |e| ≈ 1e-3, determinant ≈ 1), far enough
    # from float64's limits that A⁻¹ and the radii it gives stay moderate.
    MAX_STRETCH = 10.0
    MIN_STRETCH_DET = 1e-2
    # Largest Σ max(i, 1)·|a_i|·ρ^i allowed over the field: room below float64's 1.8e308 for the
    # products of projection (times sin θ, cos θ, ρ).
    MAX_POLY_MAGNITUDE = 1e300
    # Smallest field (degrees off axis) a model may cover: far below any real lens, even on a
    # 1-pixel image; the coefficients of a smaller one are nonsense (e.g. a0 = 1e300).
    MIN_FIELD_DEG = 0.01
    # Most coefficients of poly and invpol (real files: 5 and up to 33): poly's root finding costs
    # the cube of its degree (97 s at degree 2000; degree 50 000 ran out of memory).
    MAX_POLY_COEFFS = 32
    MAX_INVPOL_COEFFS = 64

    def _setup(self) -> None:
        poly = self._lists["poly"]
        v = self._values
        if len(poly) < 1:
            raise ModelError(f"{self.name}: parameter poly must have at least one coefficient", param="poly")
        for name, most in (("poly", self.MAX_POLY_COEFFS), ("invpol", self.MAX_INVPOL_COEFFS)):
            if len(self._lists[name]) > most:
                raise ModelError(
                    f"{self.name}: parameter {name} may have at most {most} coefficients, "
                    f"got {len(self._lists[name])}",
                    param=name,
                )
        if poly[0] <= 0.0:
            raise ModelError(
                f"{self.name}: poly[0] (a0) must be > 0 (z forward); OCamCalib files store a0 < 0 "
                f"with z backwards, got {poly[0]}",
                param="poly",
            )
        self.poly = poly
        self.cx, self.cy, self.c, self.d, self.e = v["cx"], v["cy"], v["c"], v["d"], v["e"]
        w, h = self.width, self.height
        # Real centres lie near the image centre; far outside, the image corners' radii (and
        # the polynomial's powers of them) would overflow.
        for n, value, size in (("cx", self.cx, w), ("cy", self.cy, h)):
            if not -size <= value <= 2 * size:
                raise ModelError(
                    f"{self.name}: distortion centre {n} must be within [{-size}, {2 * size}] "
                    f"(at most an image size outside the image), got {value:.6g}",
                    param=n,
                )
        for n, value in (("c", self.c), ("d", self.d), ("e", self.e)):
            if abs(value) > self.MAX_STRETCH:
                raise ModelError(
                    f"{self.name}: stretch matrix entry {n} must be within ±{self.MAX_STRETCH:g} "
                    f"(real ones are near the identity), got {value:.6g}",
                    param=n,
                )
        det = self.c - self.d * self.e
        if det < self.MIN_STRETCH_DET:
            raise ModelError(
                f"{self.name}: stretch matrix determinant c - d*e must be at least "
                f"{self.MIN_STRETCH_DET:g}, got {det:.6g}"
            )
        self.A = np.array([[self.c, self.d], [self.e, 1.0]], dtype=np.float64)
        self.A_inv = np.linalg.inv(self.A).astype(np.float64, copy=False)
        corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]])
        rho_corner = float(np.linalg.norm(self._undistorted(corners), axis=1).max())
        # dθ/dρ ∝ poly(ρ) − ρ·poly'(ρ) = Σ (1 − i) a_i ρ^i: θ increases until its first root.
        try:
            rho_turn = smallest_positive_root(
                [(1 - i) * a for i, a in enumerate(poly)], what=f"{self.name}: poly's dθ/dρ polynomial"
            )
        except ModelError as err:
            raise ModelError(str(err), param="poly") from None
        self.rho_max = min(rho_corner, rho_turn)
        self._check_poly_range()
        self.dpoly = tuple(i * a for i, a in enumerate(poly))[1:]
        self.theta_max_model = math.atan2(self.rho_max, float(_horner(poly, np.array([self.rho_max]))[0]))
        if math.degrees(self.theta_max_model) < self.MIN_FIELD_DEG:
            raise ModelError(
                f"{self.name}: poly leaves a field of only {math.degrees(self.theta_max_model):.3g}° off "
                f"axis (ρ up to {self.rho_max:.6g} px); its coefficients are out of range, got "
                f"{[float(x) for x in poly]}",
                param="poly",
            )
        # Largest error of a fitted invpol (pixels); None when the invpol was given.
        self.invpol_error_px: float | None = None
        if not self._lists["invpol"]:
            self._lists["invpol"] = self._fit_invpol()
        self.invpol = self._lists["invpol"]
        self._table: tuple[float, tuple[F64, F64, F64, F64]] | None = None

    def _check_poly_range(self) -> None:
        """ModelError unless poly and its derivative stay below MAX_POLY_MAGNITUDE for ρ up to
        ``rho_max``: Σ max(i, 1)·|a_i|·max(ρ, 1)^i bounds their values and Horner partial sums."""
        a = np.abs(np.asarray(self.poly))
        i = np.flatnonzero(a)  # zero terms: no 0 * inf
        with np.errstate(over="ignore"):
            size = float(np.sum(a[i] * np.maximum(i, 1) * max(self.rho_max, 1.0) ** i))
        if not size <= self.MAX_POLY_MAGNITUDE:  # also NaN
            raise ModelError(
                f"{self.name}: poly coefficients are too large: poly(ρ) or poly'(ρ) would exceed "
                f"{self.MAX_POLY_MAGNITUDE:g} for ρ up to {self.rho_max:.6g} px, got "
                f"{[float(x) for x in self.poly]}",
                param="poly",
            )

    def _undistorted(self, pixels: F64) -> F64:
        """(N, 2) pixels -> (N, 2) (u', v') = A⁻¹ (p − centre)."""
        return (pixels - np.array([self.cx, self.cy], dtype=np.float64)) @ self.A_inv.T

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
        u, v, ok = self._project_components(points[:, 0], points[:, 1], points[:, 2])
        return np.stack([u, v], axis=1), ok

    _components_check_field = True

    def _project_components(self, x: F64, y: F64, z: F64) -> tuple[F64, F64, Mask]:
        r = x * x
        r += y * y
        norm = r + z * z
        np.sqrt(r, out=r)  # not np.hypot: ~8x slower, and no overflow is possible here
        np.sqrt(norm, out=norm)
        theta = np.arctan2(r, z)
        # max_theta: the model's own limit or the lens's, whichever is tighter (NaN fails too).
        inside = theta <= self.max_theta * (1.0 + 1e-12)
        rho = self._seed_rho(theta, inside)
        # sin θ, cos θ of the ray without trigonometry (the zero point is invalid: 0/0 masked).
        rho, converged = self._polish_rho(rho, r / norm, z / norm, inside)
        ok = inside & converged & ((r > 0.0) | (z > 0.0))
        scale = np.divide(rho, r, out=rho, where=r > 0.0)
        scale[r == 0.0] = 0.0
        # (u, v) = A · scale·(x, y) + (cx, cy), A = [[c, d], [e, 1]]
        sx = scale * x
        scale *= y
        u = sx * self.c
        u += self.d * scale
        u += self.cx
        sx *= self.e
        sx += scale
        sx += self.cy
        return u, sx, ok

    def _seed_rho(self, theta: F64, inside: Mask) -> F64:
        """Newton's starting ρ for angles θ: the invpol (OCamCalib's world2cam), or for many
        points at once (lookup-table builds) the cubic Hermite table of the exact ρ(θ), which
        is close enough for one Newton step to confirm it."""
        th = np.where(inside, theta, 0.0)
        if th.size >= self.SEED_TABLE_MIN_POINTS:
            return self._table_seed(th)
        seed = _horner(self.invpol, th - math.pi / 2)
        return np.clip(np.where(np.isfinite(seed), seed, 0.5 * self.rho_max), 0.0, self.rho_max)

    def _seed_table(self) -> tuple[float, tuple[F64, F64, F64, F64]]:
        """(nodes per radian, (c0, c1, c2, c3) each (n,)) of a uniform θ grid on [0, θ_max]: on
        interval i, ρ(θ) = ``c0 + s(c1 + s(c2 + s·c3))`` with s in [0, 1] (cubic Hermite from the
        exact ρ and dρ/dθ at the nodes). Built once per model."""
        if self._table is None:
            n = self.SEED_TABLE_NODES
            theta = np.linspace(0.0, self.theta_max_model, n + 1)
            sin_t, cos_t = np.sin(theta), np.cos(theta)
            seed = _horner(self.invpol, theta - math.pi / 2)
            seed = np.clip(np.where(np.isfinite(seed), seed, 0.5 * self.rho_max), 0.0, self.rho_max)
            rho, _ = self._polish_rho(seed, sin_t, cos_t, np.ones(n + 1, dtype=bool))
            # dρ/dθ from f(ρ, θ) = poly(ρ) sin θ − ρ cos θ = 0, scaled to the interval width.
            f_theta = _horner(self.poly, rho) * cos_t + rho * sin_t
            f_rho = _horner(self.dpoly, rho) * sin_t - cos_t
            h = self.theta_max_model / n
            with np.errstate(all="ignore"):
                m = np.where(f_rho < 0.0, -f_theta / f_rho, 0.0) * h
            m = np.where(np.isfinite(m), m, 0.0)
            d = np.diff(rho)
            # Four contiguous arrays: four gathers beat one gather of (…, 4) rows.
            coeffs = (
                rho[:-1].copy(),
                m[:-1].copy(),
                3.0 * d - 2.0 * m[:-1] - m[1:],
                m[:-1] + m[1:] - 2.0 * d,
            )
            self._table = (n / self.theta_max_model, coeffs)
        return self._table

    def _table_seed(self, theta: F64) -> F64:
        per_rad, (c0, c1, c2, c3) = self._seed_table()
        t = theta * per_rad
        i = t.astype(np.intp)
        np.clip(i, 0, c0.size - 1, out=i)
        t -= i  # position within the interval
        out = c3[i]
        out *= t
        out += c2[i]
        out *= t
        out += c1[i]
        out *= t
        out += c0[i]
        return np.clip(out, 0.0, self.rho_max, out=out)

    def _polish_rho(self, rho: F64, sin_t: F64, cos_t: F64, inside: Mask) -> tuple[F64, Mask]:
        """Safeguarded Newton on ``f(ρ) = poly(ρ)·sin θ − ρ·cos θ`` from the seed ``rho``:
        (ρ, converged), converged also True outside (nothing to do). Each point iterates until
        its own step is below tolerance; once few are left, only those are computed."""
        shape = rho.shape
        rho = rho.reshape(-1).copy()
        s, c = sin_t.reshape(-1), cos_t.reshape(-1)
        converged = ~inside.reshape(-1)
        idx: NDArray[np.intp] | None = None  # None: every point (whole arrays, no gathering)
        lo = np.zeros_like(rho)
        hi = np.full_like(rho, self.rho_max)
        for _ in range(self.MAX_ITER):
            if idx is None:
                active = ~converged
                n_active = int(np.count_nonzero(active))
                if n_active == 0:
                    break
                if 4 * n_active < active.size:
                    idx = np.flatnonzero(active)
                    lo, hi = lo[idx], hi[idx]
            if idx is not None and idx.size == 0:
                break
            rr, si, co = (rho, s, c) if idx is None else (rho[idx], s[idx], c[idx])
            # f(ρ) = |ray(ρ)|·sin(θ − θ(ρ)): positive below the root, negative above.
            f = _horner(self.poly, rr)
            f *= si
            f -= rr * co
            fp = _horner(self.dpoly, rr)
            fp *= si
            fp -= co
            lo = np.where(f >= 0, rr, lo)
            hi = np.where(f < 0, rr, hi)
            good = fp < 0
            f /= np.where(good, fp, -1.0)
            newton = rr - f
            # A step outside the bracket (or NaN: comparisons fail) bisects instead.
            good &= newton >= lo
            good &= newton <= hi
            step = np.where(good, newton, 0.5 * (lo + hi))
            done = np.abs(step - rr) <= self.RHO_RTOL * np.maximum(1.0, rr)
            if idx is None:
                # Converged points keep their value (a whole-array loop never moves them again).
                rho = np.where(converged, rho, step)
                converged |= done
            else:
                rho[idx] = step
                converged[idx[done]] = True
                keep = ~done
                idx, lo, hi = idx[keep], lo[keep], hi[keep]
        return rho.reshape(shape), converged.reshape(shape)

    def _unproject(self, pixels: F64) -> tuple[F64, Mask]:
        undist = self._undistorted(pixels)
        rho = np.hypot(undist[:, 0], undist[:, 1])
        ok = rho <= self.rho_max * (1.0 + 1e-12)
        z = _horner(self.poly, rho)
        return np.stack([undist[:, 0], undist[:, 1], z], axis=1), ok
