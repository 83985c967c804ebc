"""Reading a map of a surface (range, depth, disparity) at fractional pixels without inventing a
surface: bilinear between neighbours that agree, the nearest one across an edge.

Linear interpolation across a depth edge makes a point between the foreground and the background
that no surface has: a phantom obstacle in a costmap. :func:`sample_surface` blends only where
the valid neighbouring pixels agree within 3 % and takes the nearest valid pixel elsewhere.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["sample_surface"]

F64 = NDArray[np.float64]


def sample_surface(image: F64, q: F64) -> F64:
    """``image`` (H, W; NaN = none) at pixels ``q`` (N, 2): bilinear among the valid neighbours
    where they agree within 3 %, else the nearest valid one (a depth edge is never blended into
    a range no surface has); NaN outside or where no neighbour is valid."""
    h, w = image.shape
    # Two NaN pixels around the map: every corner of a clipped q reads a pixel or a NaN.
    padded = np.full((h + 4, w + 4), np.nan)
    padded[2:-2, 2:-2] = image
    q = np.where(np.isfinite(q), q, -5.0)  # no pixel: outside, no neighbour
    u0 = np.clip(np.floor(q[:, 0]), -2, w).astype(np.intp)
    v0 = np.clip(np.floor(q[:, 1]), -2, h).astype(np.intp)
    fu, fv = q[:, 0] - u0, q[:, 1] - v0
    flat = padded.ravel()
    base = (v0 + 2) * (w + 4) + (u0 + 2)
    # The four neighbours as separate vectors (reductions over an axis of 4 are slow in numpy);
    # the order of the corners is the order of the nearest-pixel choice on ties.
    corners = (
        (flat[base], (1.0 - fu) * (1.0 - fv)),
        (flat[base + 1], fu * (1.0 - fv)),
        (flat[base + w + 4], (1.0 - fu) * fv),
        (flat[base + w + 5], fu * fv),
    )
    total = np.zeros(q.shape[0])
    weighted = np.zeros(q.shape[0])
    lo, hi = np.full(q.shape[0], np.inf), np.full(q.shape[0], -np.inf)
    nearest, nearest_w = np.full(q.shape[0], np.nan), np.full(q.shape[0], -1.0)
    for value, weight in corners:
        have = np.isfinite(value)
        weight = np.where(have, weight, 0.0)
        total += weight
        weighted += np.where(have, value, 0.0) * weight
        lo = np.where(have, np.minimum(lo, value), lo)
        hi = np.where(have, np.maximum(hi, value), hi)
        better = weight > nearest_w
        nearest = np.where(better, value, nearest)
        nearest_w = np.where(better, weight, nearest_w)
    with np.errstate(invalid="ignore", divide="ignore", all="ignore"):
        out: F64 = np.where(hi <= 1.03 * lo, weighted / total, nearest)
    out[total <= 0.0] = np.nan
    return out
