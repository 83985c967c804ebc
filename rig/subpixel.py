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

from concurrent.futures import Executor
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from rig.bands import run_in_bands, submit_or_run
from rig.filters import copy_where, fill_where, index_map

__all__ = [
    "Normalisation",
    "Refinement",
    "RefinementInputs",
    "confidence_from_sigma",
    "local_mean_variance",
    "normalise_contrast",
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


def normalise_contrast(img: U8) -> F32:
    """Local contrast normalisation ``(I − μ) / sqrt(σ² + ε²)`` over :data:`NORM_WINDOW`: the two
    cameras' gain and offset differences (exposure, vignetting at different field angles) would
    otherwise leak into the intensity residual and bias the step. In place with OpenCV's
    arithmetic (its ``sqrt`` is half numpy's time on float32; both are exact IEEE operations):
    this runs on every frame."""
    mu, var = local_mean_variance(img, NORM_WINDOW)
    var += np.float32(NORM_EPS**2)
    cv2.sqrt(var, dst=var)
    out = _f32(cv2.subtract(img, mu, dst=mu, dtype=cv2.CV_32F))  # μ is spent: its buffer takes I − μ
    cv2.divide(out, var, dst=out)
    return out


def local_mean_variance(image: NDArray[np.uint8] | F32, window: int) -> tuple[F32, F32]:
    """The mean and the variance (at least 0) of ``image`` (H, W) over ``window``² around each
    pixel, float32, mirrored at the border (OpenCV's default). From a uint8 image OpenCV sums
    integers: both are exact before the division."""
    k = (window, window)
    mean = _f32(cv2.boxFilter(image, cv2.CV_32F, k))
    var = _f32(cv2.sqrBoxFilter(image, cv2.CV_32F, k))
    cv2.subtract(var, cv2.multiply(mean, mean), dst=var)
    cv2.threshold(var, 0.0, 0.0, cv2.THRESH_TOZERO, dst=var)  # max(σ², 0): 8× np.maximum's speed
    return mean, var


def _box(x: F32, window: int, out: F32 | None = None) -> F32:
    """Sum of ``x`` (n, W) float32 over ``window``² (zero outside), float32 (OpenCV sums in
    double); into ``out`` if given (not ``x``)."""
    k = (window, window)
    return _f32(cv2.boxFilter(x, -1, k, dst=out, normalize=False, borderType=cv2.BORDER_CONSTANT))


def _count(mask: NDArray[np.bool_], window: int) -> F32:
    """True pixels of ``mask`` (n, W) in each ``window``² (float32): the box filter of the mask as
    uint8 sums integers, twice as fast as the float box and exact."""
    k = (window, window)
    return _f32(
        cv2.boxFilter(mask.view(np.uint8), cv2.CV_32F, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    )


def _f32(x: object) -> F32:
    """An OpenCV result as the float32 ndarray it is (for the type checker; no copy)."""
    return np.asarray(x, dtype=np.float32)


@dataclass(frozen=True)
class RefinementInputs:
    """What the refinement needs of one frame beyond the disparity's rows: the normalised images
    ``L``/``R``, their x-derivatives ``gL``/``gR`` and the matcher's disparity with NaN → 0, all
    (H, W) float32. Made once per frame by :func:`refinement_inputs`; rows of it are refined by
    :func:`refine_rows` (in bands, by the pipeline).

    ``L``, ``gL`` and ``d_clean`` may be a window of the frame's columns, from column ``x0``;
    ``R``/``gR`` are always whole: the step gathers them at ``x − d``."""

    L: F32
    R: F32
    gL: F32
    gR: F32
    d_clean: F32
    x0: int = 0

    def rows(self, rows: slice) -> RefinementInputs:
        """The same inputs for a slice of rows (views)."""
        return RefinementInputs(
            self.L[rows], self.R[rows], self.gL[rows], self.gR[rows], self.d_clean[rows], self.x0
        )


class Normalisation:
    """Both gray images' local contrast normalisation, started at construction: on a ``pool``
    (both images at once, while the caller does something else) or else here. :meth:`result`
    gives (L, R) (H, W) float32."""

    def __init__(
        self,
        left: NDArray[np.generic],
        right: NDArray[np.generic],
        pool: Executor | None = None,
        *,
        ready: bool = False,
    ) -> None:
        work = _as_is if ready else normalise_contrast
        self._left = submit_or_run(pool, work, left)
        self._right = submit_or_run(pool, work, right)

    @classmethod
    def ready(cls, left: F32, right: F32) -> Normalisation:
        """Both images' normalisation, made earlier (the coarse-to-fine search makes it)."""
        return cls(left, right, None, ready=True)

    def result(self) -> tuple[F32, F32]:
        return self._left.result(), self._right.result()


def _as_is(image: F32) -> F32:
    return image


def refinement_inputs(
    left: U8,
    right: U8,
    disparity: F32,
    pool: Executor | None = None,
    *,
    cols: slice = slice(None),
    normalised: Normalisation | None = None,
) -> RefinementInputs:
    """:class:`RefinementInputs` for gray VPC images (H, W) uint8 and the matcher's disparity;
    with a ``pool`` the two images are normalised in parallel, unless ``normalised`` (their
    :class:`Normalisation`, started earlier) is given. ``cols`` (step 1): the columns to
    refine, of which ``L``, ``gL`` and ``d_clean`` are made. (The images are normalised whole:
    OpenCV's box filter rounds its last few columns differently from the rest, so a window of
    them would not be exactly the whole frame's.)"""
    L, R = (normalised or Normalisation(left, right, pool)).result()
    d_clean: F32 = np.asarray(cv2.patchNaNs(disparity[:, cols].copy(), 0.0), dtype=np.float32)  # NaN -> 0
    x0 = cols.indices(left.shape[1])[0]
    return RefinementInputs(L[:, cols], R, _x_derivative(L)[:, cols], _x_derivative(R), d_clean, x0)


def refine_rows(
    inputs: RefinementInputs,
    disparity: F32,
    valid: NDArray[np.bool_],
    window: int,
    *,
    apply: bool = True,
    want_sigma: bool = False,
) -> Refinement:
    """:func:`refine_disparity` of the rows ``disparity``/``valid`` (the matcher's, (n, w); NaN
    exactly where invalid) are of; ``inputs`` are the frame's, sliced to the same rows (and
    columns, see :class:`RefinementInputs`) by the caller. Pixels within ``window // 2`` of a cut
    that is not the image border see a truncated window: give a margin
    (:func:`rig.bands.run_in_bands`), or cut where no pixel within that margin is valid (invalid
    pixels add nothing to the sums)."""
    L, R, gL, gR, d_clean = inputs.L, inputs.R, inputs.gL, inputs.gR, inputs.d_clean
    h, w = L.shape
    xs = np.arange(inputs.x0, inputs.x0 + w, dtype=np.float32)[None, :]
    ys = index_map((h, w), 0)
    d0 = np.rint(d_clean)
    # Integer gather R(x - d0) and ∂R(x - d0) through remap (nearest: exact on integer maps).
    map_x = np.subtract(xs, d0)
    e = _f32(cv2.remap(R, map_x, ys, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE))
    g = _f32(cv2.remap(gR, map_x, ys, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE))
    # ḡ zero at invalid pixels so that they do not vote in their neighbours' windows (e needs
    # no zeroing: it only enters multiplied by ḡ, and its residual is zeroed in _sigma). In place,
    # OpenCV arithmetic (numpy's where a scalar is involved: OpenCV's is slower there); spent
    # buffers are reused, which keeps the working set in cache.
    cv2.add(g, gL, dst=g)
    cv2.multiply(g, valid.view(np.uint8), dst=g, scale=0.5, dtype=cv2.CV_32F)
    cv2.subtract(e, L, dst=e)
    a = cv2.multiply(d0, g, dst=map_x)  # the map is spent: its buffer takes (d0·ḡ + e)·ḡ
    cv2.add(a, e, dst=a)
    cv2.multiply(a, g, dst=a)
    g2 = _f32(cv2.multiply(g, g))
    sum_g2 = _box(g2, window)
    # NaN at invalid pixels (0·NaN; +0 elsewhere, exact): so are the refined values and σ below,
    # which saves masking the many invalid pixels there.
    cv2.scaleAdd(disparity, 0.0, sum_g2, dst=sum_g2)
    best = _box(_f32(a), window)
    cv2.divide(best, sum_g2, dst=best)  # IEEE division: NaN/inf where Σḡ² = 0, never ok below
    ok = _f32(cv2.absdiff(best, d_clean, dst=g2)) <= np.float32(MAX_STEP_PX)  # False where NaN
    rejected = ~ok
    rejected &= valid  # few
    copy_where(best, d_clean, rejected)  # the matcher's value where the step is not trusted
    sig: F32 | None = None
    if want_sigma:
        residual = _f32(cv2.subtract(best if apply else disparity, d0, dst=a))
        sig = _sigma(residual, e, g, sum_g2, valid, rejected, window, scratch=g2)
    return Refinement(best if apply else disparity, sig)


def _sigma(
    r: F32,
    e: F32,
    g: F32,
    sum_g2: F32,
    valid: NDArray[np.bool_],
    rejected: NDArray[np.bool_],
    window: int,
    scratch: F32,
) -> F32:
    """Predicted σ_d (n, W) of each window from the residuals ``e − r·ḡ`` under the disparity
    (``r``: its difference from d0; all (n, W) float32, ``r`` and ``Σḡ²`` NaN and ``ḡ`` zero at
    invalid pixels); inf at invalid and ``rejected`` pixels, where Σḡ² = 0 and where fewer than
    3 pixels of the window are valid. ``r`` and ``scratch`` (a spent buffer) are overwritten."""
    cv2.multiply(r, g, dst=r)
    cv2.subtract(e, r, dst=r)
    cv2.patchNaNs(r, 0.0)  # invalid pixels have no residual
    cv2.multiply(r, r, dst=r)
    sig = _box(r, window, out=scratch)
    n = _count(valid, window)
    n -= np.float32(1.0)
    cv2.threshold(n, 1.5, 0.0, cv2.THRESH_TOZERO, dst=n)  # n − 1 < 2 → 0: σ = x/0 → inf or NaN
    cv2.divide(sig, n, dst=sig)
    cv2.divide(sig, sum_g2, dst=sig)
    cv2.sqrt(sig, dst=sig)
    cv2.patchNaNs(sig, np.inf)  # invalid pixels and 0/0 (inf stays inf)
    fill_where(sig, np.inf, rejected)
    return sig


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
    ``disparity`` (H, W) float32 (NaN exactly where ``valid`` is False).

    ``apply=False`` keeps the matcher's values and only predicts σ (confidence without
    refinement). Pixels whose refined value moved more than :data:`MAX_STEP_PX` keep the
    matcher's value and get σ = inf. Cost: two 5-tap filters, two nearest remaps and two box
    filters (two more with σ, and a uint8 one), all float32.

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
    conf = np.divide(sigma, np.float32(-sigma0), dtype=np.float32)
    # Not cv2.exp: a quarter of numpy's time on normal results, but 100× slower where they are
    # subnormal or 0 (σ > 87 σ0, σ unknown).
    np.exp(conf, out=conf)
    out: F32 = conf
    return out
