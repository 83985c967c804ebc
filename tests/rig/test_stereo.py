"""Stereo parameters (ROS names), the OpenCV matchers and the subpixel step on exact shifts.

The synthetic pairs here are sums of sinusoids evaluated at x and x + d: an exactly shifted,
band-limited texture with no resampling at all, so the true disparity is d everywhere.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from numpy.typing import NDArray
from pydantic import ValidationError

from rig.errors import PipelineError
from rig.filters import left_right_consistent
from rig.stereo import SGBM_MODES, SeenColumns, StereoMatcher, StereoParams, create_opencv_matcher
from rig.subpixel import confidence_from_sigma, refine_disparity, refine_rows, refinement_inputs

U8 = NDArray[np.uint8]


def shifted_pair(d: float, h: int = 120, w: int = 200, seed: int = 0, noise: float = 0.0) -> tuple[U8, U8]:
    """Left image T(x, y) and right image T(x + d, y): true disparity d at every pixel."""
    rng = np.random.default_rng(seed)
    n = 120
    f = rng.uniform(0.01, 0.22, n)
    ang = rng.uniform(0.0, 2 * np.pi, n)
    phase = rng.uniform(0.0, 2 * np.pi, n)
    amp = 1.0 / np.sqrt(f)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)

    def texture(shift: float) -> NDArray[np.float64]:
        t = np.zeros((h, w))
        for k in range(n):
            t += amp[k] * np.cos(
                2 * np.pi * f[k] * (np.cos(ang[k]) * (x + shift) + np.sin(ang[k]) * y) + phase[k]
            )
        return t

    left, right = texture(0.0), texture(d)
    scale = 45.0 / left.std()
    out = []
    for img in (left, right):
        v = 128 + (img - left.mean()) * scale + rng.normal(0.0, noise, img.shape)
        out.append(np.clip(np.rint(v), 0, 255).astype(np.uint8))
    return out[0], out[1]


ROI = (slice(10, -10), slice(80, -10))  # right of the matcher's unmatched left band
#: The exact search: OpenCV's matcher over the whole range, its left-right check's too, so that
#: the result is the bare matcher's (the coarse-to-fine search's own tests are in
#: test_stereo_coarse_to_fine.py, the half-resolution check's in test_half_check.py).
EXACT = {"coarse_to_fine": False, "lr_check_scale": 1}


def test_defaults_follow_ros_names_and_reach_three_and_a_half_baselines() -> None:
    p = StereoParams()
    ros_names = {
        "stereo_algorithm",
        "prefilter_size",
        "prefilter_cap",
        "correlation_window_size",
        "min_disparity",
        "disparity_range",
        "uniqueness_ratio",
        "texture_threshold",
        "speckle_size",
        "speckle_range",
        "disp12_max_diff",
        "P1",
        "P2",
        "full_dp",
        "sgbm_mode",
    }
    assert ros_names <= set(StereoParams.model_fields)
    assert p.stereo_algorithm == 1
    # Default VPC: 640 px over 90° -> fx = 320; 3.5 baselines out is d = 320 / 3.5 ≈ 91 px. No
    # further: every disparity more lets a repetitive texture's next period in (docs/stereo.md).
    assert 320 / 3.5 <= p.min_disparity + p.disparity_range - 1 < 320 / 3
    assert p.lr_check, "the left-right check removes most phantom obstacles"
    assert p.penalties() == (8 * 7 * 7, 32 * 7 * 7)
    assert StereoParams(P1=100, P2=900).penalties() == (100, 900)


def test_ros_sgbm_mode_numbers_and_full_dp() -> None:
    assert [StereoParams(sgbm_mode=i).sgbm_mode for i in range(4)] == ["sgbm", "hh", "3way", "hh4"]
    assert StereoParams(sgbm_mode="HH4").sgbm_mode == "hh4"
    assert StereoParams(full_dp=True, sgbm_mode="sgbm").effective_mode == "hh"
    assert set(SGBM_MODES) == {"sgbm", "hh", "3way", "hh4"}


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"correlation_window_size": 8}, "correlation_window_size must be odd"),
        ({"disparity_range": 100}, "multiple of 16"),
        ({"stereo_algorithm": 0, "correlation_window_size": 3}, "block matching"),
        ({"full_dp": True}, "full_dp conflicts"),
        ({"P1": 500, "P2": 400}, "P2"),
        ({"median": 4}, "median"),
        ({"temporal_alpha": 1.0}, "temporal_alpha"),
        ({"stereo_algorithm": 2}, "stereo_algorithm"),
        ({"sgbm_mode": "fast"}, "sgbm_mode"),
        ({"disparity_rnage": 64}, "disparity_rnage"),
    ],
)
def test_bad_parameters_are_rejected_naming_the_field(kwargs: dict[str, object], field: str) -> None:
    with pytest.raises(ValidationError, match=field):
        StereoParams(**kwargs)


@pytest.mark.parametrize("algorithm", [0, 1])
def test_matchers_find_the_shift(algorithm: int) -> None:
    left, right = shifted_pair(23.4)
    params = StereoParams(stereo_algorithm=algorithm, correlation_window_size=9, disparity_range=64, **EXACT)
    res = StereoMatcher(params).match(left, right)
    assert res.disparity.dtype == np.float32 and res.valid.dtype == bool
    assert np.isnan(res.disparity[~res.valid]).all()
    d = res.disparity[ROI][res.valid[ROI]]
    assert res.valid[ROI].mean() > 0.9
    assert abs(np.median(d) - 23.4) < 0.35


@pytest.mark.parametrize("min_disparity", [0, 8])
def test_disparity_is_opencvs_fixed_point_with_nan_exactly_where_invalid(min_disparity: int) -> None:
    left, right = shifted_pair(23.4)
    params = StereoParams(min_disparity=min_disparity, disparity_range=64, **EXACT)
    fixed = create_opencv_matcher(params).compute(left, right)  # the bare OpenCV call
    matcher = StereoMatcher(params)
    res = matcher.match(left, right)
    expected_valid = fixed >= min_disparity * 16
    assert 0.2 < expected_valid.mean() < 1.0  # both kinds of pixel are there
    np.testing.assert_array_equal(res.valid, expected_valid)
    np.testing.assert_array_equal(np.isnan(res.disparity), ~expected_valid)
    np.testing.assert_array_equal(res.disparity[expected_valid], fixed[expected_valid] / np.float32(16.0))
    # The right view's disparity (the LR check's) marks its invalid pixels the same way.
    right_disp = matcher.right_disparity(left, right)
    flipped = create_opencv_matcher(params).compute(
        np.ascontiguousarray(right[:, ::-1]), np.ascontiguousarray(left[:, ::-1])
    )[:, ::-1]
    np.testing.assert_array_equal(np.isnan(right_disp), flipped < min_disparity * 16)


def speckled_pair() -> tuple[U8, U8]:
    """A shifted pair (disparity 19.3) with 8×8 patches of the left image copied from the right
    one 45 px away: small blobs of a consistent wrong disparity, speckles for the matcher's
    speckle removal to remove."""
    left, right = shifted_pair(19.3, h=160, w=260, noise=2.0)
    rng = np.random.default_rng(7)
    left = left.copy()
    for y, x in rng.integers((10, 110), (140, 240), size=(30, 2)):
        left[y : y + 8, x : x + 8] = right[y : y + 8, x - 45 : x - 37]
    return left, right


@pytest.mark.parametrize(
    "stereo",
    [
        {"stereo_algorithm": 0, "correlation_window_size": 9},
        *({"sgbm_mode": mode} for mode in SGBM_MODES),
        {"min_disparity": -8, "speckle_size": 40, "speckle_range": 4},
        {"min_disparity": 4, "speckle_size": 200, "speckle_range": 1},
        {"lr_check": True},
    ],
    ids=lambda s: ",".join(f"{k}={v}" for k, v in s.items()),
)
def test_speckles_removed_after_compute_are_the_bare_matchers(stereo: dict[str, object]) -> None:
    """:meth:`StereoMatcher.compute` leaves SGBM's speckle removal to
    :meth:`~StereoMatcher.finish` (so a pipeline overlaps it with the next pair's match): the
    result is the bare OpenCV matcher's, bit for bit, for every matcher."""
    left, right = speckled_pair()
    params = StereoParams(disparity_range=64, **EXACT, **stereo)
    bare = create_opencv_matcher(params).compute(left, right)
    matcher = StereoMatcher(params)
    unfiltered = matcher.compute(left, right)
    removed = (unfiltered.left != bare).sum()
    if params.stereo_algorithm == 0:
        assert removed == 0, "StereoBM removes its speckles itself"
        without = create_opencv_matcher(params.model_copy(update={"speckle_size": 0}))
        removed = (without.compute(left, right) != bare).sum()
    assert removed > 50, "no speckles to remove: the test pair proves nothing"
    np.testing.assert_array_equal(matcher.raw(left, right), bare)
    res = matcher.disparity_of(unfiltered)
    filtered = unfiltered.left.copy()  # finish filtered it in place; a second pass changes nothing
    matcher.remove_speckles(unfiltered.left)
    np.testing.assert_array_equal(unfiltered.left, filtered)
    valid = bare >= params.min_disparity * 16
    disparity = bare / np.float32(16.0)
    if params.lr_check:  # against the bare matcher's view of the mirrored pair
        mirrored = create_opencv_matcher(params).compute(
            np.ascontiguousarray(right[:, ::-1]), np.ascontiguousarray(left[:, ::-1])
        )[:, ::-1]
        right_disp = np.where(mirrored >= params.min_disparity * 16, mirrored / np.float32(16.0), np.nan)
        np.testing.assert_array_equal(matcher.right_disparity(left, right), right_disp)
        blind = left.shape[1] - (params.min_disparity + params.disparity_range)
        valid &= left_right_consistent(disparity, valid, right_disp.astype(np.float32), 1.0, blind)
    np.testing.assert_array_equal(res.valid, valid)
    np.testing.assert_array_equal(res.disparity[valid], disparity[valid])
    assert np.isnan(res.disparity[~valid]).all()


def test_seen_columns_at_a_coarser_scale_keep_every_partly_seen_column() -> None:
    seen = SeenColumns((3, 17), (0, 20))
    assert seen.at_scale(2) == SeenColumns((1, 9), (0, 10))
    assert seen.at_scale(4) == SeenColumns((0, 5), (0, 5))


@pytest.mark.parametrize(
    "stereo", [{}, {"min_disparity": -8}, {"stereo_algorithm": 0}], ids=["sgbm", "negative-min", "bm"]
)
def test_matching_only_the_seen_columns(stereo: dict[str, int]) -> None:
    # The right lens sees nothing left of column 60: the mirrored run leaves those columns (and
    # the ones only they need) out, and gives the whole image's right disparity elsewhere.
    left, right = shifted_pair(17.6, w=240)
    params = StereoParams(disparity_range=64, **EXACT, **stereo)
    matcher = StereoMatcher(params)
    whole = matcher.compute(left, right)
    seen = SeenColumns(left=(0, 240), right=(60, 240))
    cropped = matcher.compute(left, right, seen)
    np.testing.assert_array_equal(cropped.left, whole.left)  # the left lens sees every column
    assert cropped.mirrored is not None and whole.mirrored is not None
    invalid = (params.min_disparity - 1) * 16
    margin = (
        max(params.correlation_window_size, params.prefilter_size * (params.stereo_algorithm == 0)) // 2 + 1
    )
    # Mirrored, original column x is 239 - x: left of column 60 - margin nothing was matched.
    assert (cropped.mirrored[:, 240 - 60 + margin :] == invalid).all()
    assert (whole.mirrored[:, 240 - 60 + margin :] != invalid).mean() > 0.8, "nothing to leave out"
    # Mirrored columns of every seen x the whole image's mirrored run matches (x >= 60).
    seen_part = (slice(10, -10), slice(params.blind_band_px, 240 - 60))
    same = cropped.mirrored[seen_part] == whole.mirrored[seen_part]
    assert same.mean() > 0.97, f"{same.mean():.4f}"
    close = np.abs(cropped.mirrored[seen_part].astype(int) - whole.mirrored[seen_part]) <= 16
    assert close.mean() > 0.999
    assert cropped.right_unsearched_from == whole.right_unsearched_from == 240 - params.blind_band_px
    # A lens that sees every column: the whole image, bit for bit.
    full = matcher.compute(left, right, SeenColumns(left=(0, 240), right=(0, 240)))
    assert full.mirrored is not None
    np.testing.assert_array_equal(full.mirrored, whole.mirrored)
    # Masks to spans: the first and past-the-last column any row sees.
    valid = np.zeros((5, 240), dtype=bool)
    valid[2, 30:200] = True
    valid[4, 25:90] = True
    assert SeenColumns.of(valid, np.zeros_like(valid)) == SeenColumns(left=(25, 200), right=(0, 0))


def test_matcher_rejects_bad_images() -> None:
    left, right = shifted_pair(10.0)
    m = StereoMatcher(StereoParams(disparity_range=64))
    with pytest.raises(PipelineError, match="gray uint8"):
        m.match(left, right[:, :-1])
    with pytest.raises(PipelineError, match="gray uint8"):
        m.match(left.astype(np.float32), right)
    with pytest.raises(PipelineError, match="no column"):
        StereoMatcher(StereoParams(disparity_range=256)).match(left, right)


def test_right_disparity_from_the_mirrored_pair() -> None:
    left, right = shifted_pair(17.6)
    m = StereoMatcher(StereoParams(disparity_range=64))
    dr = m.right_disparity(left, right)
    # The right view's reference band is on the other side: its right-most columns are unmatched.
    inner = dr[10:-10, 10:-80]
    assert np.isfinite(inner).mean() > 0.9
    assert abs(np.nanmedian(inner) - 17.6) < 0.35


@pytest.mark.parametrize("d", [10.1, 15.25, 20.4, 25.5, 30.6, 35.75, 40.9])
def test_subpixel_step_removes_pixel_locking_on_exact_shifts(d: float) -> None:
    left, right = shifted_pair(d)
    raw = StereoMatcher(StereoParams(disparity_range=64, subpixel=False, **EXACT)).match(left, right)
    ref = refine_disparity(left, right, raw.disparity, raw.valid, 15)
    ok = raw.valid[ROI]
    plain = np.sqrt(np.mean((raw.disparity[ROI][ok] - d) ** 2))
    ours = np.sqrt(np.mean((ref.disparity[ROI][ok] - d) ** 2))
    assert ours < 0.05, f"refined RMS {ours:.3f} px at d = {d}"
    if abs(d - round(d)) >= 0.25:  # SGBM is locked to whole pixels away from them
        assert plain > 0.1 and ours < plain / 3
    assert np.isnan(ref.disparity[~raw.valid]).all()


def test_refinement_is_invariant_to_gain_and_offset_between_cameras() -> None:
    left, right = shifted_pair(20.4)
    darker = np.clip(right.astype(np.float32) * 0.8 + 12, 0, 255).astype(np.uint8)
    raw = StereoMatcher(StereoParams(disparity_range=64)).match(left, darker)
    ref = refine_disparity(left, darker, raw.disparity, raw.valid, 15)
    ok = raw.valid[ROI]
    assert np.sqrt(np.mean((ref.disparity[ROI][ok] - 20.4) ** 2)) < 0.06


def test_predicted_sigma_grows_with_noise_and_confidence_falls() -> None:
    sig_medians = []
    for noise in (0.0, 4.0, 12.0):
        left, right = shifted_pair(20.4, noise=noise, seed=3)
        raw = StereoMatcher(StereoParams(disparity_range=64, **EXACT)).match(left, right)
        ref = refine_disparity(left, right, raw.disparity, raw.valid, 15, want_sigma=True)
        assert ref.sigma is not None and ref.sigma.dtype == np.float32
        assert np.isinf(ref.sigma[~raw.valid]).all()
        s = ref.sigma[ROI][raw.valid[ROI]]
        err = np.abs(ref.disparity[ROI][raw.valid[ROI]] - 20.4)
        sig_medians.append(float(np.median(s)))
        # The prediction is calibrated to within a factor of ~3 of the actual spread.
        if noise > 0:
            actual = float(np.sqrt(np.mean(err**2)))
            assert actual / 3 < float(np.sqrt(np.mean(s**2))) < actual * 3
    assert sig_medians[0] < sig_medians[1] < sig_medians[2]
    conf = confidence_from_sigma(np.array([0.0, 0.1, 1.0, np.inf], dtype=np.float32), 0.1)
    assert conf[0] == 1.0 and conf[1] == pytest.approx(np.exp(-1)) and conf[3] == 0.0
    assert np.all(np.diff(conf) < 0)


def test_refinement_without_apply_keeps_the_matchers_values() -> None:
    left, right = shifted_pair(12.3)
    raw = StereoMatcher(StereoParams(disparity_range=64)).match(left, right)
    ref = refine_disparity(left, right, raw.disparity, raw.valid, 15, apply=False, want_sigma=True)
    assert np.array_equal(ref.disparity, raw.disparity, equal_nan=True)
    assert ref.sigma is not None and np.isfinite(ref.sigma[ROI][raw.valid[ROI]]).mean() > 0.9


@pytest.mark.parametrize("bands", [2, 3, 4, 7])
def test_banded_refinement_is_the_single_pass(bands: int) -> None:
    left, right = shifted_pair(17.35, noise=3.0, seed=5)
    raw = StereoMatcher(StereoParams(disparity_range=64)).match(left, right)
    whole = refine_disparity(left, right, raw.disparity, raw.valid, 15, want_sigma=True)
    with ThreadPoolExecutor(2) as pool:
        banded = refine_disparity(
            left, right, raw.disparity, raw.valid, 15, want_sigma=True, pool=pool, bands=bands
        )
    # Every row sees the same neighbourhood: only the box filters' summation order differs.
    assert np.array_equal(np.isnan(whole.disparity), np.isnan(banded.disparity))
    assert np.nanmax(np.abs(whole.disparity - banded.disparity)) < 1e-4
    assert whole.sigma is not None and banded.sigma is not None
    finite = np.isfinite(whole.sigma)
    assert np.array_equal(finite, np.isfinite(banded.sigma))
    rel = np.abs(whole.sigma[finite] - banded.sigma[finite]) / whole.sigma[finite]
    assert np.median(rel) < 1e-3 and rel.max() < 0.1  # float32 running sums: round-off only


@pytest.mark.parametrize("apply", [True, False])
def test_refinement_of_a_column_window_is_exactly_the_whole_frames(apply: bool) -> None:
    """What the pipeline does: refine only the columns around the valid pixels (the matcher's
    unmatched left band is left out), with L, gL and d_clean made for those columns only."""
    left, right = shifted_pair(17.35, noise=3.0, seed=5)
    raw = StereoMatcher(StereoParams(disparity_range=64)).match(left, right)
    first = int(np.flatnonzero(raw.valid.any(axis=0))[0])
    assert first >= 64
    whole = refine_disparity(left, right, raw.disparity, raw.valid, 15, apply=apply, want_sigma=True)
    for c0 in (first - 9, first - 1):  # with a margin and without one: invalid pixels add nothing
        cols = slice(c0, left.shape[1])
        inputs = refinement_inputs(left, right, raw.disparity, cols=cols)
        assert inputs.x0 == c0 and inputs.L.shape[1] == inputs.d_clean.shape[1] == left.shape[1] - c0
        part = refine_rows(
            inputs, raw.disparity[:, cols], raw.valid[:, cols], 15, apply=apply, want_sigma=True
        )
        assert np.array_equal(part.disparity, whole.disparity[:, cols], equal_nan=True)
        assert whole.sigma is not None and part.sigma is not None
        assert np.array_equal(part.sigma, whole.sigma[:, cols])
        # And row slices of a window keep its columns.
        rows = inputs.rows(slice(5, 50))
        assert rows.x0 == c0 and rows.R.shape[1] == left.shape[1]


def test_lr_check_through_the_matcher_removes_inconsistent_pixels() -> None:
    left, right = shifted_pair(15.3)
    # Paint an occluder into the left view only: those pixels have no true match on the right.
    left = left.copy()
    left[40:80, 120:150] = 255 - left[40:80, 120:150]
    base = StereoMatcher(StereoParams(disparity_range=64, speckle_size=0, lr_check=False)).match(left, right)
    lr = StereoMatcher(StereoParams(disparity_range=64, speckle_size=0, lr_check=True)).match(left, right)
    assert not (lr.valid & ~base.valid).any(), "the LR check only removes pixels"
    occ = (slice(42, 78), slice(122, 148))
    assert lr.valid[occ].mean() < 0.5 * max(base.valid[occ].mean(), 0.02) or lr.valid[occ].mean() < 0.1
    assert lr.valid[ROI].mean() > 0.6
