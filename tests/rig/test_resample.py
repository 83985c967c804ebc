"""Reading a surface map at fractional pixels (rig.resample): exact on a smooth surface, never a
value between two surfaces at an edge, holes not filled from afar."""

from __future__ import annotations

import numpy as np

from rig.resample import sample_surface


def test_a_smooth_surface_is_read_bilinearly() -> None:
    v, u = np.mgrid[0:20, 0:30].astype(np.float64)
    ramp = 5.0 + 0.01 * u + 0.02 * v  # a plane in range: bilinear is exact
    rng = np.random.default_rng(0)
    q = np.stack([rng.uniform(0, 29, 500), rng.uniform(0, 19, 500)], axis=1)
    got = sample_surface(ramp, q)
    assert np.allclose(got, 5.0 + 0.01 * q[:, 0] + 0.02 * q[:, 1], atol=1e-12)


def test_an_edge_is_never_blended_and_holes_are_not_filled() -> None:
    step = np.where(np.arange(10)[None, :] < 5, 1.0, 4.0) * np.ones((6, 1))
    q = np.stack([np.linspace(3.0, 6.0, 61), np.full(61, 2.5)], axis=1)
    got = sample_surface(step, q)
    assert set(np.unique(got).tolist()) <= {1.0, 4.0}  # one surface or the other, never between
    assert (got[q[:, 0] < 4.5] == 1.0).all() and (got[q[:, 0] > 4.5] == 4.0).all()
    holes = np.full((6, 10), np.nan)
    holes[2, 2] = 3.0
    near = sample_surface(holes, np.array([[2.4, 2.4], [3.9, 3.9], [-5.0, 1.0], [np.nan, 1.0]]))
    assert near[0] == 3.0 and np.isnan(near[1:]).all()  # a neighbour counts, a pixel two away does not
