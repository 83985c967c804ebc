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
    q = np.where(np.isfinite(q), q, -2.0)  # no pixel: outside, no neighbour
    u0 = np.floor(q[:, 0]).astype(np.int64)
    v0 = np.floor(q[:, 1]).astype(np.int64)
    fu, fv = q[:, 0] - u0, q[:, 1] - v0
    values = np.full((q.shape[0], 4), np.nan)
    weights = np.zeros((q.shape[0], 4))
    for k, (du, dv) in enumerate(((0, 0), (1, 0), (0, 1), (1, 1))):
        u, v = u0 + du, v0 + dv
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        values[inside, k] = image[v[inside], u[inside]]
        weights[:, k] = (fu if du else 1.0 - fu) * (fv if dv else 1.0 - fv)
    have = np.isfinite(values)
    weights = np.where(have, weights, 0.0)
    total = weights.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore", all="ignore"):
        lo, hi = (
            np.nanmin(np.where(have, values, np.inf), axis=1),
            np.nanmax(np.where(have, values, -np.inf), axis=1),
        )
        blended = np.nansum(np.where(have, values, 0.0) * weights, axis=1) / total
        nearest = values[np.arange(q.shape[0]), np.argmax(weights, axis=1)]
        out: F64 = np.where(hi <= 1.03 * lo, blended, nearest)
    out[total <= 0.0] = np.nan
    return out
