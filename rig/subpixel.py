"""Subpixel disparity refinement against SGBM's pixel locking.

SGBM interpolates its cost minimum with a parabola; on Birchfield-Tomasi costs that pulls the
disparity towards whole pixels (~0.2 px RMS on noise-free fractional shifts). We refine
each disparity with one symmetric Gauss-Newton (Lucas-Kanade) step on the image intensities:

* ``d0 = round(d_sgbm)`` per pixel; ``Rs(x) = R(x - d0(x))`` is an exact integer gather (no
  interpolation, so no interpolation bias), ``e = Rs - L``.
* Symmetric linearisation: ``R(x - d0) - L(x) ≈ (d - d0) · ḡ`` with ``ḡ = (∂L(x) + ∂R(x - d0)) / 2``,
  exact to second order in ``d - d0`` (one-sided gradients leave a first-order bias).
* A window W solves for one common disparity with each pixel relative to its *own* d0:
  ``d = Σ_W (ḡ e + d0 ḡ²) / Σ_W ḡ²`` — box filters of per-pixel products, so the whole image
  costs a few OpenCV passes.
* Both images are first normalised to local zero mean and unit contrast (15 px window), so
  gain/offset differences between the cameras (exposure, vignetting at different field angles)
  do not bias the step; without it 1.5 grey levels of noise plus the prototype's vignetting
  raised the error on a plane from 0.04 to 0.19 px RMS.
* ∂ is a 5-tap derivative (``[1, -8, 0, 8, -1] / 12``): the central difference's sin(ω)/ω gain loss
  over-scales the step on fine texture.

The residuals ``r = e − (d − d0)·ḡ`` of each pixel under its refined disparity give the
least-squares prediction of the disparity's standard deviation ``σ_d = sqrt(Σ_W r² / (n − 1) / Σ_W ḡ²)``
(image noise over texture energy), which :func:`confidence_from_sigma` maps into [0, 1].
"""

from __future__ import annotations

import functools
from concurrent.futures import Executor
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from rig.bands import run_in_bands

__all__ = [
    "Refinement",
    "RefinementInputs",
    "confidence_from_sigma",
    "refine_disparity",
    "refine_rows",
    "refinement_inputs",
]

U8 = NDArray[np.uint8]
F32 = NDArray[np.float32]

_DERIV5 = np.array([[1.0, -8.0, 0.0, 8.0, -1.0]], dtype=np.float32) / 12.0
# A refined value further than this from the matcher's is not trusted (the step is linearised
# around d0): the pixel keeps the matcher's disparity.
MAX_STEP_PX = 1.0
# Local contrast normalisation before the step: window (px) and noise floor (grey levels).
NORM_WINDOW = 15
NORM_EPS = 2.0


@dataclass
class Refinement:
    """``disparity`` (H, W) float32 px (NaN invalid); ``sigma`` (H, W) float32 predicted σ_d in
    px (inf where unknown) or None when not asked for."""

    disparity: F32
    sigma: F32 | None


def _x_derivative(img: F32) -> F32:
    return np.asarray(
        cv2.filter2D(img, cv2.CV_32F, _DERIV5, borderType=cv2.BORDER_REPLICATE), dtype=np.float32
    )


@functools.lru_cache(maxsize=8)
def _grid(h: int, w: int) -> tuple[F32, F32]:
    """Column indices (1, W) and the row map (H, W) float32 for remap; cached per size."""
    xs = np.arange(w, dtype=np.float32)[None, :]
    ys = np.ascontiguousarray(np.broadcast_to(np.arange(h, dtype=np.float32)[:, None], (h, w)))
    ys.flags.writeable = False
    return xs, ys


def _normalise(img: U8) -> F32:
    """Local contrast normalisation ``(I − μ) / sqrt(σ² + ε²)`` over :data:`NORM_WINDOW`: the two
    cameras' gain and offset differences (exposure, vignetting at different field angles) would
    otherwise leak into the intensity residual and bias the step. Means straight from the uint8
    image (OpenCV sums integers), the rest in place: this runs on every frame."""
    k = (NORM_WINDOW, NORM_WINDOW)
    mu = np.asarray(cv2.boxFilter(img, cv2.CV_32F, k), dtype=np.float32)
    scale = np.asarray(cv2.sqrBoxFilter(img, cv2.CV_32F, k), dtype=np.float32)
    scale -= mu * mu
    np.maximum(scale, np.float32(0.0), out=scale)
    scale += np.float32(NORM_EPS**2)
    np.sqrt(scale, out=scale)
    out = img.astype(np.float32)
    out -= mu
    out /= scale
    return out


def _box(x: F32, window: int) -> F32:
    out = cv2.boxFilter(x, -1, (window, window), normalize=False, borderType=cv2.BORDER_CONSTANT)
    return np.asarray(out, dtype=np.float32)


@dataclass(frozen=True)
class RefinementInputs:
    """What the refinement needs of one frame beyond the disparity's rows: the normalised images
    ``L``/``R``, their x-derivatives ``gL``/``gR`` and the matcher's disparity with NaN → 0, all
    (H, W) float32. Made once per frame by :func:`refinement_inputs`; rows of it are refined by
    :func:`refine_rows` (in bands, by the pipeline)."""

    L: F32
    R: F32
    gL: F32
    gR: F32
    d_clean: F32

    def rows(self, rows: slice) -> RefinementInputs:
        """The same inputs for a slice of rows (views)."""
        return RefinementInputs(self.L[rows], self.R[rows], self.gL[rows], self.gR[rows], self.d_clean[rows])


def refinement_inputs(left: U8, right: U8, disparity: F32, pool: Executor | None = None) -> RefinementInputs:
    """:class:`RefinementInputs` for gray VPC images (H, W) uint8 and the matcher's disparity;
    with a ``pool`` the two images are normalised in parallel."""
    if pool is None:
        L, R = _normalise(left), _normalise(right)
    else:
        try:
            right_future = pool.submit(_normalise, right)
        except RuntimeError:  # the pool was shut down (replaced) meanwhile
            return refinement_inputs(left, right, disparity)
        L = _normalise(left)
        R = right_future.result()
    d_clean: F32 = np.asarray(cv2.patchNaNs(disparity.copy(), 0.0), dtype=np.float32)  # NaN -> 0
    return RefinementInputs(L, R, _x_derivative(L), _x_derivative(R), d_clean)


def refine_rows(
    inputs: RefinementInputs,
    disparity: F32,
    valid: NDArray[np.bool_],
    window: int,
    *,
    apply: bool = True,
    want_sigma: bool = False,
) -> Refinement:
    """:func:`refine_disparity` of the rows ``disparity``/``valid`` (the matcher's, (n, W)) are
    of; ``inputs`` are the frame's, sliced to the same rows by the caller. Rows within
    ``window // 2`` of a cut that is not the image border see a truncated window: give a margin
    (:func:`rig.bands.run_in_bands`)."""
    L, R, gL, gR, d_clean = inputs.L, inputs.R, inputs.gL, inputs.gR, inputs.d_clean
    h, w = L.shape
    xs, ys = _grid(h, w)
    vf = valid.astype(np.float32)
    d0 = np.rint(d_clean)
    # Integer gather R(x - d0) and ∂R(x - d0) through remap (nearest: exact on integer maps).
    map_x = xs - d0
    Rs: F32 = np.asarray(cv2.remap(R, map_x, ys, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE))
    gRs = cv2.remap(gR, map_x, ys, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    # Invalid pixels (g = e = 0) do not vote in their neighbours' windows.
    g = gL + gRs
    g *= vf
    g *= np.float32(0.5)
    e = Rs
    e -= L
    e *= vf
    a = d0 * g
    a += e
    a *= g
    sum_g2 = _box(g * g, window)
    with np.errstate(divide="ignore", invalid="ignore"):
        refined = _box(a, window)
        refined /= sum_g2
        ok = np.abs(refined - d_clean) <= MAX_STEP_PX
    ok &= valid
    best = np.where(ok, refined, d_clean)
    sig: F32 | None = None
    if want_sigma:
        # Residual of each pixel under its own disparity (small numbers: float32 is enough).
        r = best - d0 if apply else d_clean - d0
        r *= g
        np.subtract(e, r, out=r)
        r *= r
        n = _box(vf, window)
        with np.errstate(divide="ignore", invalid="ignore"):
            sig = _box(r, window)
            sig /= np.maximum(n - np.float32(1.0), np.float32(1.0))
            sig /= sum_g2
            np.sqrt(sig, out=sig)
            ok &= (n >= 3) & np.isfinite(sig)
        sig[~ok] = np.inf
    if not apply:
        return Refinement(disparity, sig)
    best[~valid] = np.nan
    return Refinement(best, sig)


def refine_disparity(
    left: U8,
    right: U8,
    disparity: F32,
    valid: NDArray[np.bool_],
    window: int = 11,
    *,
    apply: bool = True,
    want_sigma: bool = False,
    pool: Executor | None = None,
    bands: int = 1,
) -> Refinement:
    """Refined disparity for gray VPC images ``left``/``right`` (H, W) uint8 and the matcher's
    ``disparity`` (H, W) float32 (NaN where ``valid`` is False).

    ``apply=False`` keeps the matcher's values and only predicts σ (confidence without
    refinement). Pixels whose refined value moved more than :data:`MAX_STEP_PX` keep the
    matcher's value and get σ = inf. Cost: two 5-tap filters, two nearest remaps and two box
    filters (three more with σ), all float32.

    With a ``pool``, the two images are normalised in parallel and the rest runs as ``bands``
    horizontal bands (each with ``window // 2`` rows of margin, so every row sees the same
    neighbourhood as in one pass; only the box filters' summation order differs, ~1e-7 px):
    on a multi-core CPU this cuts the stage's latency, not its CPU time.
    """
    h, w = left.shape
    inputs = refinement_inputs(left, right, disparity, pool)
    out = np.empty((h, w), dtype=np.float32) if apply else disparity
    sigma = np.empty((h, w), dtype=np.float32) if want_sigma else None

    def band(a: int, b: int, r0: int, r1: int) -> None:
        rows = slice(a, b)
        part = refine_rows(
            inputs.rows(rows), disparity[rows], valid[rows], window, apply=apply, want_sigma=want_sigma
        )
        keep = slice(r0 - a, r1 - a)
        if apply:
            out[r0:r1] = part.disparity[keep]
        if sigma is not None and part.sigma is not None:
            sigma[r0:r1] = part.sigma[keep]

    run_in_bands(band, h, bands, window // 2, pool)
    return Refinement(out, sigma)


def confidence_from_sigma(sigma: F32, sigma0: float) -> F32:
    """Confidence in [0, 1]: ``exp(-σ_d / σ0)``; 0 where σ is unknown (inf)."""
    out: F32 = np.exp(-sigma / np.float32(sigma0)).astype(np.float32)
    return out
