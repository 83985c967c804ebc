"""Reading a surface map at fractional pixels (rig.resample): exact on a smooth surface, never a
value between two surfaces at an edge, holes not filled from afar."""

from __future__ import annotations

import numpy as np
import pytest

from rig.resample import corners_at, padded_surface, sample_padded, sample_surface


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


def test_a_padded_map_and_shared_corners_read_what_sample_surface_does() -> None:
    """The panorama pads each map once and reads the disparity and the confidence at the range's
    last pixels: the same values, bit for bit, as a call per read; corners of another size are
    refused."""
    rng = np.random.default_rng(1)
    maps = [rng.uniform(1.0, 5.0, (12, 17)) for _ in range(2)]
    maps[0][rng.random((12, 17)) < 0.2] = np.nan
    q = np.stack([rng.uniform(-2, 18, 400), rng.uniform(-2, 13, 400)], axis=1)
    q[::37] = np.nan
    corners = corners_at((12, 17), q)
    for image in maps:
        shared = sample_padded(padded_surface(image), corners)
        assert np.array_equal(shared, sample_surface(image, q), equal_nan=True)
    with pytest.raises(ValueError, match="another size"):
        sample_padded(padded_surface(np.ones((5, 5))), corners)
