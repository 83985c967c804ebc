"""Measurements on fisheye images for the honest renderer's fit (``bench.lens_fit``): edge width
(and the Gaussian σ it means), noise against brightness, and brightness of the same scene point
in two cameras.

* **Edge width**: at edge pixels (Canny) with a clear step, the grey-level profile across the
  edge (along the gradient, ±:data:`EDGE_REACH_PX`, bilinear) is normalised between its two
  plateaus; its 10–90 % rise distance is the width. Kept are steps of at least
  :data:`MIN_CONTRAST` grey levels whose plateaus are flat and whose profile rises once (no other
  edge in the window), unsaturated. A scene's edges are never sharper than the lens makes them,
  so a low percentile (:data:`WIDTH_PERCENTILE`) of the widths in a field-angle bin is the lens's;
  :func:`sigma_from_width` turns it into a Gaussian σ through the same measurement on synthetic
  edges of known σ (integrated over the pixel, 1 grey level of noise).
* **Noise**: Immerkær's estimator (the image convolved with a Laplacian-difference mask, whose
  response to a plane is zero) in 8×8 blocks; per brightness bin a low percentile of the blocks
  (the flattest: texture only adds).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = [
    "EDGE_REACH_PX",
    "MIN_CONTRAST",
    "WIDTH_PERCENTILE",
    "EdgeSamples",
    "edge_widths",
    "noise_blocks",
    "sigma_from_width",
    "width_calibration",
]

F64 = NDArray[np.float64]
Mask = NDArray[np.bool_]

EDGE_REACH_PX = 8.0
MIN_CONTRAST = 30.0
WIDTH_PERCENTILE = 20.0
_STEP = 0.25
_OFFSETS = np.arange(-EDGE_REACH_PX, EDGE_REACH_PX + 1e-9, _STEP)
_PLATEAU = 8  # samples (2 px) at each end of the profile


class EdgeSamples(NamedTuple):
    """Measured edges: pixel ``x``, ``y``, 10–90 % ``width`` (px) and the unit gradient
    direction ``normal`` (N, 2)."""

    x: F64
    y: F64
    width: F64
    normal: F64


def _crossing(f: F64, level: float) -> F64:
    """Per row of ``f`` (rising 0 → 1), where it crosses ``level`` nearest the middle (offsets)."""
    above = f >= level
    rises = above[:, 1:] & ~above[:, :-1]
    mid = f.shape[1] // 2
    j = np.arange(f.shape[1] - 1)
    dist = np.where(rises, np.abs(j - mid), np.iinfo(np.int64).max)
    k = np.argmin(dist, axis=1)
    rows = np.arange(f.shape[0])
    a, b = f[rows, k], f[rows, k + 1]
    out = _OFFSETS[k] + _STEP * (level - a) / np.where(b > a, b - a, 1.0)
    return np.where(rises[rows, k], out, np.nan)


def edge_widths(
    image: NDArray[np.generic], valid: Mask, rng: np.random.Generator, most: int = 8000
) -> EdgeSamples:
    """Edges in ``image`` (grey) inside ``valid``, at most ``most`` of them (a random choice)."""
    img = np.asarray(image, dtype=np.float32)
    edges = cv2.Canny(np.clip(img, 0, 255).astype(np.uint8), 60, 150, L2gradient=True)
    edges[~valid] = 0
    ys, xs = np.nonzero(edges)
    if ys.size > most:
        pick = rng.choice(ys.size, most, replace=False)
        ys, xs = ys[pick], xs[pick]
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3)[ys, xs]
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3)[ys, xs]
    normal = np.stack([gx, gy], axis=1).astype(np.float64)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    px = (xs[:, None] + _OFFSETS[None, :] * normal[:, :1]).astype(np.float32)
    py = (ys[:, None] + _OFFSETS[None, :] * normal[:, 1:]).astype(np.float32)
    if px.size == 0:
        return EdgeSamples(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros((0, 2)))
    prof = cv2.remap(img, px, py, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
    lo, hi = prof[:, :_PLATEAU].mean(axis=1), prof[:, -_PLATEAU:].mean(axis=1)
    contrast = hi - lo
    flat = np.maximum(prof[:, :_PLATEAU].std(axis=1), prof[:, -_PLATEAU:].std(axis=1))
    variation = np.abs(np.diff(prof, axis=1)).sum(axis=1)
    ok = (contrast >= MIN_CONTRAST) & (flat < 0.08 * contrast) & (variation < 1.15 * contrast)
    ok &= (prof.max(axis=1) < 250) & (prof.min(axis=1) > 3)
    f = (prof - lo[:, None]) / np.where(contrast > 0, contrast, 1.0)[:, None]
    width = _crossing(f, 0.9) - _crossing(f, 0.1)
    ok &= np.isfinite(width) & (width > 0)
    return EdgeSamples(xs[ok].astype(np.float64), ys[ok].astype(np.float64), width[ok], normal[ok])


def _synthetic_edges(sigma: float, rng: np.random.Generator, size: int = 400, oversample: int = 8) -> F64:
    """Rectangles of random grey at random angles, blurred with σ ``sigma`` px, integrated over
    each pixel (area resampling), 1 grey level of noise."""
    big = size * oversample
    img: NDArray[np.float32] = np.full((big, big), 60.0, np.float32)
    for _ in range(25):
        centre = rng.uniform(0.1, 0.9, 2) * big
        sides = rng.uniform(0.05, 0.2, 2) * big
        box = cv2.boxPoints(((centre[0], centre[1]), (sides[0], sides[1]), rng.uniform(0, 180)))
        cv2.fillPoly(img, [box.astype(np.int32)], float(rng.uniform(60, 220)))
    if sigma > 0:
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), sigma * oversample), np.float32)
    small = cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA).astype(np.float64)
    out: F64 = small + rng.normal(0.0, 1.0, small.shape)
    return out


def width_calibration(rng: np.random.Generator, images: int = 3) -> tuple[F64, F64]:
    """(σ, the :data:`WIDTH_PERCENTILE` percentile of the measured widths) on synthetic edges."""
    sigmas = np.array([0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 2.5, 3.0])
    widths = []
    for s in sigmas:
        measured = []
        for _ in range(images):
            img = _synthetic_edges(float(s), rng)
            valid = np.zeros(img.shape, bool)
            valid[12:-12, 12:-12] = True
            measured.append(edge_widths(img, valid, rng).width)
        widths.append(float(np.percentile(np.concatenate(measured), WIDTH_PERCENTILE)))
    return sigmas, np.maximum.accumulate(np.array(widths))


def sigma_from_width(width: F64 | float, calibration: tuple[F64, F64]) -> F64:
    """The Gaussian σ (px) whose synthetic edges measure ``width``; 0 below the sharpest."""
    sigmas, widths = calibration
    return np.asarray(np.interp(width, widths, sigmas, left=0.0, right=math.nan), dtype=np.float64)


_IMMERKAER = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], dtype=np.float64)


def noise_blocks(image: NDArray[np.generic], valid: Mask, block: int = 8) -> tuple[F64, F64]:
    """Per ``block``×``block`` block wholly inside ``valid``: its mean grey level and the noise σ
    Immerkær's estimator gives there."""
    img = np.asarray(image, dtype=np.float64)
    response = np.abs(cv2.filter2D(img, cv2.CV_64F, _IMMERKAER, borderType=cv2.BORDER_REFLECT))
    h, w = (img.shape[0] // block) * block, (img.shape[1] // block) * block

    def blocks(a: NDArray[np.generic]) -> NDArray[np.generic]:
        return (
            a[:h, :w].reshape(h // block, block, w // block, block).swapaxes(1, 2).reshape(-1, block * block)
        )

    inside = blocks(valid).all(axis=1)
    mean = blocks(img).mean(axis=1)[inside]
    sigma = math.sqrt(math.pi / 2.0) * blocks(response).mean(axis=1)[inside] / 6.0
    return mean, sigma
