"""The left-right check's second search at half resolution (rig.half_check, ``lr_check_scale``):
the upsampling against the field it came from, the check's right view against the full-resolution
search's on exactly shifted pairs, and the served left view against the exact search's. Its
effect on renders (phantoms, the bars placed too far) is test_phantoms.py's; on the real ring,
bench.ring_consistency's (docs/stereo.md, "Left-right check at half resolution")."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from rig.disparity import UnfilteredDisparity
from rig.half_check import upsampled_mirrored
from rig.stereo import HALF_CHECK_TOLERANCE, StereoMatcher, StereoParams
from tests.rig.test_stereo import ROI, shifted_pair

I16 = NDArray[np.int16]


def _coarse_mirrored(right_view: NDArray[np.float64]) -> I16:
    """A perfect half-resolution search's mirrored output for a right view's disparity (H, W)
    px: the 2×2 block means (the last column repeated, as :func:`downsample` pads), halved, in
    1/16 coarse px, mirrored."""
    h, w = right_view.shape
    padded = np.pad(right_view, ((0, h % 2), (0, w % 2)), mode="edge")
    means = padded.reshape(padded.shape[0] // 2, 2, padded.shape[1] // 2, 2).mean(axis=(1, 3))
    return np.rint(means / 2 * 16)[:, ::-1].astype(np.int16)


@pytest.mark.parametrize("width", [200, 201])
def test_upsampled_mirrored_is_the_full_resolution_field(width: int) -> None:
    """A right view with a depth step at column 101 (40 px left of it, 20 right), through a
    perfect half-resolution search and back: twice the coarse disparity, in the right columns
    (an odd width pads the coarse images on the right, so on the mirrored view's left)."""
    h, step = 40, 101
    right_view = np.where(np.arange(width) < step, 40.0, 20.0)[None, :].repeat(h, axis=0)
    coarse = _coarse_mirrored(right_view)
    full = upsampled_mirrored(coarse, 0, (h, width), -16)
    assert full.shape == (h, width)
    back = full[:, ::-1] / 16.0
    away = np.abs(np.arange(width) - step) > 2
    assert np.array_equal(back[:, away], right_view[:, away])
    # The step lies where it was: the middle of the blend within a pixel of it.
    middle = np.flatnonzero(back[h // 2] <= 30.0)[0]
    assert abs(middle - step) <= 1


def test_an_invalid_coarse_pixel_invalidates_only_what_it_takes_part_in() -> None:
    h, w = 20, 30
    coarse = _coarse_mirrored(np.full((h, w), 24.0))
    coarse[4, 7] = -16  # invalid (below the smallest disparity, 0)
    full = upsampled_mirrored(coarse, 0, (h, w), -16)
    invalid = full == -16
    rows, cols = np.nonzero(invalid)
    # Its own 2×2 full pixels, and the bilinear blend's reach: one full pixel around them.
    assert invalid[8:10, 14:16].all()
    assert rows.min() >= 7 and rows.max() <= 10 and cols.min() >= 13 and cols.max() <= 16
    assert (full[~invalid] == 24 * 16).all()


@pytest.mark.parametrize("d", [9.3, 23.4, 41.75])
def test_the_check_s_right_view_is_the_full_search_s(d: float) -> None:
    left, right = shifted_pair(d, w=201, noise=1.0)
    half = StereoMatcher(StereoParams(disparity_range=64, lr_check_scale=2)).compute(left, right)
    full = StereoMatcher(StereoParams(disparity_range=64, lr_check_scale=1)).compute(left, right)
    assert half.mirrored is not None and full.mirrored is not None
    half_view, full_view = (m[:, ::-1][ROI[0], 10:-80] / 16.0 for m in (half.mirrored, full.mirrored))
    both = (half_view >= 0) & (full_view >= 0)
    assert both.mean() > 0.9
    # SGBM's subpixel disparity leans towards whole pixels, coarse ones here (0.575 px off at 9.3).
    assert abs(np.median(half_view[both]) - d) < 0.6
    assert np.mean(np.abs(half_view[both] - full_view[both]) <= HALF_CHECK_TOLERANCE) > 0.97


def test_the_served_disparities_are_the_exact_search_s() -> None:
    """The half-resolution check changes which pixels pass, never a value: the left view is the
    exact search's, bit for bit."""
    left, right = shifted_pair(23.4, w=201, noise=1.0)
    half_matcher = StereoMatcher(StereoParams(disparity_range=64))
    full_matcher = StereoMatcher(StereoParams(disparity_range=64, lr_check_scale=1))
    half_raw, full_raw = half_matcher.compute(left, right), full_matcher.compute(left, right)
    assert (half_raw.check_scale, full_raw.check_scale) == (2, 1)
    assert np.array_equal(half_raw.left, full_raw.left)
    half, full = half_matcher.disparity_of(half_raw), full_matcher.disparity_of(full_raw)
    both = half.valid & full.valid
    assert np.array_equal(half.disparity[both], full.disparity[both])
    assert abs(half.valid[ROI].mean() - full.valid[ROI].mean()) < 0.02


def test_the_check_runs_at_half_resolution_only_for_the_exact_sgbm_search_with_the_check() -> None:
    default = StereoParams()
    assert default.check_factor == 2 and default.lr_tolerance(2) == HALF_CHECK_TOLERANCE * default.lr_max_diff
    for other in (
        StereoParams(lr_check_scale=1),
        StereoParams(coarse_to_fine=True),
        StereoParams(lr_check=False),
        StereoParams(stereo_algorithm=0),
    ):
        assert other.check_factor == 1 and other.lr_tolerance(1) == other.lr_max_diff
    level = StereoParams(min_disparity=8, disparity_range=112).check_level()
    # Half the disparities, rounded up to 16, over the range only; the coarse level's stiffer P2.
    assert (level.min_disparity, level.disparity_range) == (4, 64)
    assert StereoParams().penalties()[1] < level.P2 and level.check_factor == 1
    assert level.speckle_size == StereoParams().speckle_size // 4


def test_a_pair_too_narrow_for_the_half_resolution_range_is_checked_at_full_resolution() -> None:
    """112 disparities need 113 columns at full resolution but 129 at half (the half range, 56,
    rounds up to 64): a 120-column pair gets the full-resolution check, not an error."""
    left, right = shifted_pair(20.5, w=120)
    half = StereoMatcher(StereoParams(disparity_range=112))
    assert half.params.check_level().blind_band_px == 64
    full = StereoMatcher(StereoParams(disparity_range=112, lr_check_scale=1))
    found, expected = half.compute(left, right), full.compute(left, right)
    assert found.mirrored is not None and expected.mirrored is not None
    assert np.array_equal(found.mirrored, expected.mirrored)
    # ... and at the full resolution's tolerance: the same pixels pass.
    assert found.check_scale == 1 and expected.check_scale == 1
    assert np.array_equal(half.disparity_of(found).valid, full.disparity_of(expected).valid)


@pytest.mark.parametrize("check_scale", [1, 2])
def test_speckles_are_removed_once_at_the_resolution_searched(check_scale: int) -> None:
    """A full-resolution check's mirrored view has its speckles removed in ``disparity_of``; a
    half-resolution one had them removed before its upsampling (rig.half_check), so a small
    patch in the upsampled view (four coarse pixels' worth) stays and the left pixels that match
    into it keep their agreement."""
    p = StereoParams(speckle_size=50, speckle_range=1)
    matcher = StereoMatcher(p)
    h, w, d = 40, 80, 10
    left = np.full((h, w), d * 16, dtype=np.int16)
    right_view = np.full((h, w), 2 * d, dtype=np.float64)  # disagrees everywhere...
    right_view[18:22, 38:42] = d  # ...but on a 4×4 patch, a speckle at full resolution
    mirrored = np.rint(right_view * 16)[:, ::-1].astype(np.int16)
    unfiltered = UnfilteredDisparity(left, mirrored, right_unsearched_from=w, check_scale=check_scale)
    valid = matcher.disparity_of(unfiltered).valid
    kept = valid[18:22, 38 + d : 42 + d]
    assert valid.sum() == kept.sum()  # only the pixels matching into the patch agree
    assert kept.all() == (check_scale == 2)
