"""Reading a map of a surface (range, depth, disparity) at fractional pixels without inventing a
surface: bilinear between neighbours that agree, the nearest one across an edge.

Linear interpolation across a depth edge makes a point between the foreground and the background
that no surface has: a phantom obstacle in a costmap. :func:`sample_surface` blends only where
the valid neighbouring pixels agree within 3 % and takes the nearest valid pixel elsewhere.
A caller reading one map at several sets of pixels, or several maps at the same pixels, pads
the map once (:func:`padded_surface`) and finds the pixels' corners once (:func:`corners_at`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Corners", "PaddedSurface", "corners_at", "padded_surface", "sample_padded", "sample_surface"]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class PaddedSurface:
    """A map (H, W; NaN = none) with two NaN pixels around it, flattened."""

    flat: F64
    height: int
    width: int


@dataclass(frozen=True)
class Corners:
    """The four neighbours of N pixels of an (H, W) map, as indices into its padded form and
    bilinear weights, in the order of the nearest-pixel choice on ties."""

    index: tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]
    weight: tuple[F64, F64, F64, F64]
    height: int
    width: int


def padded_surface(image: F64) -> PaddedSurface:
    """``image`` (H, W) padded for :func:`sample_padded`."""
    h, w = image.shape
    # Two NaN pixels around the map: every corner of a clipped pixel reads a pixel or a NaN.
    padded = np.full((h + 4, w + 4), np.nan)
    padded[2:-2, 2:-2] = image
    return PaddedSurface(padded.ravel(), h, w)


def corners_at(shape: tuple[int, int], q: F64) -> Corners:
    """The corners of pixels ``q`` (N, 2) in a map of ``shape`` (H, W)."""
    h, w = shape
    q = np.where(np.isfinite(q), q, -5.0)  # no pixel: outside, no neighbour
    u0 = np.clip(np.floor(q[:, 0]), -2, w).astype(np.intp)
    v0 = np.clip(np.floor(q[:, 1]), -2, h).astype(np.intp)
    fu, fv = q[:, 0] - u0, q[:, 1] - v0
    base = (v0 + 2) * (w + 4) + (u0 + 2)
    index = (base, base + 1, base + w + 4, base + w + 5)
    weight = ((1.0 - fu) * (1.0 - fv), fu * (1.0 - fv), (1.0 - fu) * fv, fu * fv)
    return Corners(index, weight, h, w)


def sample_padded(surface: PaddedSurface, corners: Corners) -> F64:
    """:func:`sample_surface` of a padded map at the pixels of ``corners`` (of a map its size)."""
    if (corners.height, corners.width) != (surface.height, surface.width):
        raise ValueError("sample_padded: the corners are of a map of another size")
    n = corners.index[0].shape[0]
    total = np.zeros(n)
    weighted = np.zeros(n)
    lo, hi = np.full(n, np.inf), np.full(n, -np.inf)
    nearest, nearest_w = np.full(n, np.nan), np.full(n, -1.0)
    # The four neighbours as separate vectors (reductions over an axis of 4 are slow in numpy).
    for index, corner_weight in zip(corners.index, corners.weight, strict=True):
        value = surface.flat[index]
        have = np.isfinite(value)
        weight = np.where(have, corner_weight, 0.0)
        total += weight
        weighted += np.where(have, value, 0.0) * weight
        lo, hi = np.fmin(lo, value), np.fmax(hi, value)  # (fmin and fmax pass a NaN value over)
        better = weight > nearest_w
        nearest = np.where(better, value, nearest)
        nearest_w = np.where(better, weight, nearest_w)
    with np.errstate(invalid="ignore", divide="ignore", all="ignore"):
        out: F64 = np.where(hi <= 1.03 * lo, weighted / total, nearest)
    out[total <= 0.0] = np.nan
    return out


def sample_surface(image: F64, q: F64) -> F64:
    """``image`` (H, W; NaN = none) at pixels ``q`` (N, 2): bilinear among the valid neighbours
    where they agree within 3 %, else the nearest valid one (a depth edge is never blended into
    a range no surface has); NaN outside or where no neighbour is valid."""
    return sample_padded(padded_surface(image), corners_at((image.shape[0], image.shape[1]), q))
