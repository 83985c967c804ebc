"""Levenberg-Marquardt for bundle problems whose unknowns are a few camera parameters plus one
6-DoF pose per view, where each residual row depends on the camera parameters and on the pose of
its own view only (calibration.solver builds such problems).

The normal equations are formed in block form and the pose unknowns eliminated by the Schur
complement, so a step costs a few small solves (scipy's least_squares would factorise the whole
Jacobian, QR/SVD, at every step or iterate with LSMR: ~100x slower on these problems). Steps
are projected onto bounds; robust losses use IRLS weights per corner.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import LinAlgError, cho_factor, cho_solve

from calibration.errors import CalibrationFailed

__all__ = ["LOSSES", "BlockProblem", "NormalEquations", "corner_weights", "levenberg_marquardt"]

F64 = NDArray[np.float64]

LOSSES = ("linear", "huber", "soft_l1")


class BlockProblem(Protocol):
    """What the solver needs from a problem: residuals (M,) interleaved u, v per corner, and the
    compact Jacobian ``(Jc (M, n_cam), Jp (M, 6))`` (see calibration.solver)."""

    V: int  # number of views
    view_col0: int  # number of camera unknowns (they come first in x)
    n_res: int
    row_order: NDArray[np.int_]  # rows sorted by view
    view_starts: NDArray[np.int_]  # first sorted row of each view

    def residuals(self, x: F64) -> F64: ...

    def jacobian(self, x: F64) -> tuple[F64, F64]: ...


def corner_weights(r: F64, loss: str, f_scale: float) -> tuple[F64, float]:
    """IRLS weights per residual row (2 per corner) and the robust cost of residuals (M,)."""
    e2 = r[0::2] ** 2 + r[1::2] ** 2
    k2 = f_scale * f_scale
    if loss not in LOSSES:
        raise CalibrationFailed(f"unknown loss {loss!r} ({', '.join(LOSSES)})")
    if loss == "linear":
        w = np.ones_like(e2)
        cost = e2
    elif loss == "huber":
        big = e2 > k2
        w = np.where(big, f_scale / np.sqrt(np.where(big, e2, 1.0)), 1.0)
        cost = np.where(big, 2.0 * f_scale * np.sqrt(e2) - k2, e2)
    else:  # soft_l1
        root = np.sqrt(1.0 + e2 / k2)
        w = 1.0 / root
        cost = 2.0 * k2 * (root - 1.0)
    return np.repeat(w, 2), float(cost.sum())


class NormalEquations:
    """JᵀWJ and JᵀWr in block form: camera block ``A`` (n_cam, n_cam), per-view pose blocks
    ``B`` (V, 6, 6) and couplings ``C`` (V, n_cam, 6); gradient ``gc`` (n_cam,), ``gp`` (V, 6).
    Pose unknowns are eliminated by the Schur complement, so a step costs a few small solves
    rather than a factorisation of the full (n_cam + 6V)² system."""

    def __init__(self, prob: BlockProblem, Jc: F64, Jp: F64, w: F64, r: F64) -> None:
        V = prob.V
        order = prob.row_order
        starts = prob.view_starts
        Jcw = Jc * w[:, None]
        Jpw = Jp * w[:, None]
        self.A: F64 = Jc.T @ Jcw
        self.gc: F64 = Jcw.T @ r
        # Per-row outer products summed per view (rows sorted by view, then reduceat).
        self.B: F64 = np.add.reduceat((Jp[:, :, None] * Jpw[:, None, :])[order], starts, axis=0).reshape(
            V, 6, 6
        )
        self.C: F64 = np.add.reduceat((Jcw[:, :, None] * Jp[:, None, :])[order], starts, axis=0).reshape(
            V, Jc.shape[1], 6
        )
        self.gp: F64 = np.add.reduceat((Jpw * r[:, None])[order], starts, axis=0)
        self.diag_c: F64 = np.diag(self.A).copy()
        self.diag_p: F64 = np.einsum("vii->vi", self.B).copy()
        top = max(float(self.diag_c.max(initial=0.0)), float(self.diag_p.max(initial=0.0)), 1e-300)
        self.diag_c = np.maximum(self.diag_c, 1e-12 * top)
        self.diag_p = np.maximum(self.diag_p, 1e-12 * top)

    def gradient_norm(self) -> float:
        """Largest scaled gradient entry max |g| / sqrt(diag)."""
        gc = np.abs(self.gc) / np.sqrt(self.diag_c) if self.gc.size else np.zeros(0)
        gp = np.abs(self.gp) / np.sqrt(self.diag_p)
        return float(max(gc.max(initial=0.0), gp.max(initial=0.0)))

    def _damped_pose_blocks(self, lam: float) -> F64:
        # Each view's block plus λ times its own diagonal.
        return self.B + lam * (self.diag_p[:, :, None] * np.eye(6))

    def schur(self, lam: float) -> F64:
        """Camera-block Schur complement with damping λ (Marquardt)."""
        Bl = self._damped_pose_blocks(lam)
        BinvCt = np.linalg.solve(Bl, np.transpose(self.C, (0, 2, 1)))  # (V, 6, n_cam)
        S = self.A + lam * np.diag(self.diag_c)
        S -= np.einsum("vcj,vjd->cd", self.C, BinvCt)
        return S

    def step(self, lam: float) -> tuple[F64, F64]:
        """Solve the damped normal equations: (camera step (n_cam,), pose steps (V, 6))."""
        Bl = self._damped_pose_blocks(lam)
        Binv_gp = np.linalg.solve(Bl, self.gp[:, :, None])[:, :, 0]  # (V, 6)
        if self.gc.size:
            S = self.schur(lam)
            rhs = -(self.gc - np.einsum("vcj,vj->c", self.C, Binv_gp))
            dc = cho_solve(cho_factor(S), rhs)
        else:
            dc = np.zeros(0)
        dp = -np.linalg.solve(Bl, (self.gp + np.einsum("vcj,c->vj", self.C, dc))[:, :, None])[:, :, 0]
        return dc, dp


def levenberg_marquardt(
    prob: BlockProblem, x: F64, lo: F64, hi: F64, loss: str, f_scale: float, max_iter: int, tol: float
) -> tuple[F64, int, bool, str]:
    """Minimise the (robust) cost from ``x`` within [lo, hi]: Levenberg-Marquardt with
    Marquardt's diagonal scaling on the Schur-reduced normal equations. Stops when the relative
    cost decrease or step falls below ``tol``, the scaled gradient vanishes, or no damping gives
    a decrease. Returns (x, residual evaluations, converged, message)."""
    nc = prob.view_col0
    r = prob.residuals(x)
    w, cost = corner_weights(r, loss, f_scale)
    nfev, lam, nu = 1, 1e-3, 2.0
    for it in range(max_iter):
        Jc, Jp = prob.jacobian(x)
        nfev += 2 * (nc + 6)
        normal = NormalEquations(prob, Jc, Jp, w, r)
        if normal.gradient_norm() <= tol * max(math.sqrt(cost), 1e-300):
            return x, nfev, True, f"converged after {it} iterations (gradient)"
        while True:
            try:
                dc, dp = normal.step(lam)
                delta = np.concatenate([dc, dp.reshape(-1)])
            except (LinAlgError, np.linalg.LinAlgError):
                delta = np.full_like(x, np.nan)
            x_new = np.clip(x + delta, lo, hi)
            cost_new = math.inf
            if np.isfinite(x_new).all():
                r_new = prob.residuals(x_new)
                nfev += 1
                w_new, cost_new = corner_weights(r_new, loss, f_scale)
            if cost_new < cost:
                break
            lam *= nu
            nu *= 2.0
            if lam > 1e16:
                return x, nfev, True, f"converged after {it} iterations (no further decrease)"
        step = x_new - x
        decrease = cost - cost_new
        x, r, w, cost = x_new, r_new, w_new, cost_new
        lam, nu = max(lam / 3.0, 1e-12), 2.0
        if decrease <= tol * cost or np.all(np.abs(step) <= tol * (np.abs(x) + tol)):
            return x, nfev, True, f"converged after {it + 1} iterations"
    return x, nfev, False, f"stopped after {max_iter} iterations without converging"
