"""The coarse-to-fine search (rig.coarse_to_fine, rig.band_search): its parts against independent
references (block means, a brute-force block matcher in numpy), and the whole on exactly shifted
pairs. Its accuracy on renders is measured with the pipeline's (test_stereo_render.py,
test_filters.py, test_pipeline.py, test_phantoms.py, test_wide_pair_study.py)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from rig.band_search import NONE, Hypothesis, of_rows, search_rows
from rig.coarse_to_fine import band_hypotheses, downsample, hypotheses
from rig.stereo import StereoMatcher, StereoParams
from rig.subpixel import normalise_contrast
from tests.rig.test_stereo import ROI, shifted_pair

U8 = NDArray[np.uint8]


@pytest.mark.parametrize("subpixel", [True, False])
@pytest.mark.parametrize("d", [9.3, 23.4, 41.75])
def test_finds_the_shift_in_both_views(d: float, subpixel: bool) -> None:
    left, right = shifted_pair(d, noise=1.0)
    params = StereoParams(coarse_to_fine=True, disparity_range=64, subpixel=subpixel)
    assert params.coarse_factor == 2
    matcher = StereoMatcher(params)
    raw = matcher.compute(left, right)
    assert raw.mirrored is not None and raw.normalised is not None
    right_view = raw.mirrored[:, ::-1] / 16.0  # the right view's disparity, still unfiltered
    assert abs(np.median(right_view[10:-10, 10:-80]) - d) < 0.6
    res = matcher.disparity_of(raw)
    ok = res.valid[ROI]
    assert ok.mean() > 0.9
    found = res.disparity[ROI][ok]
    if subpixel:  # whole pixels: the refinement after it takes them to subpixel precision
        assert np.array_equal(found, np.rint(found)) and abs(np.median(found) - d) <= 0.5
    else:  # the block costs' parabola
        assert abs(np.median(found) - d) < 0.35 and np.sqrt(np.mean((found - d) ** 2)) < 0.35


def test_downsampling_is_the_block_mean() -> None:
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (37, 50), dtype=np.uint8)
    for scale in (2, 4):
        coarse = downsample(image, scale)
        h, w = -(-37 // scale), -(-50 // scale)
        assert coarse.shape == (h, w)
        padded = np.pad(image.astype(np.float64), ((0, h * scale - 37), (0, w * scale - 50)), mode="edge")
        means = padded.reshape(h, scale, w, scale).mean(axis=(1, 3))
        assert np.abs(coarse - means).max() <= 0.5 + 1e-9  # rounded to uint8


def test_hypotheses_propose_both_sides_of_a_depth_edge() -> None:
    coarse = np.full((6, 10), 10.0, dtype=np.float32)
    coarse[:, 5:] = 20.0  # an edge between coarse columns 4 and 5
    coarse[0, 0] = np.nan
    up, low, high = hypotheses(coarse, (12, 20), 2)
    assert (up.half_width, low.half_width, high.half_width) == (1, 0, 0)
    # Full-resolution columns 8..11 lie next to the edge: the bilinear field blurs it, the
    # neighbourhood's extremes are the two sides' disparities (×2: full-resolution pixels).
    assert set(np.unique(up.centre[6, 8:12])) - {20, 40} != set()
    assert (low.centre[6, 8:12] == 20).all() and (high.centre[6, 8:12] == 40).all()
    # Far from the edge all three agree; an invalid coarse pixel gets its neighbours' extremes
    # (the bilinear field proposes nothing there, and next to it the nearest valid value).
    assert (up.centre[6, :4] == 20).all() and (low.centre[6, :4] == 20).all()
    assert (up.centre[:2, :2] == NONE).all() and (up.centre[:2, 2:4] == 20).all()
    assert (low.centre[:2, :2] == 20).all() and (high.centre[:2, :2] == 20).all()
    lone = np.full((4, 4), np.nan, dtype=np.float32)
    lone[0, 0] = 7.0
    near = hypotheses(lone, (8, 8), 2)
    assert (near[1].centre[4:, 4:] == NONE).all(), "no valid coarse neighbour: no hypothesis"
    assert (near[1].centre[:4, :4] == 14).all()


def test_inward_hypotheses_keep_away_from_invalid_coarse_pixels() -> None:
    """``coarse_confirm``'s hypotheses: none within ``inward`` coarse px of an invalid coarse
    pixel (its own included), the others as without it; the image's border does not count."""
    coarse = np.full((10, 12), 10.0, dtype=np.float32)
    coarse[5, 6] = np.nan
    plain = hypotheses(coarse, (20, 24), 2)
    for inward in (0, 2):
        kept = hypotheses(coarse, (20, 24), 2, inward)
        rows, cols = np.mgrid[0:20, 0:24] // 2
        near = (np.abs(rows - 5) <= inward) & (np.abs(cols - 6) <= inward)
        for mine, theirs in zip(kept, plain, strict=True):
            assert (mine.centre[near] == NONE).all()
            np.testing.assert_array_equal(mine.centre[~near], theirs.centre[~near])
        assert (kept[0].centre[0, :] == 20).all() and (kept[0].centre[:, -1] == 20).all()


def _brute_force(
    ref: U8, other: U8, centre: NDArray[np.int16], half: int, window: int, d_range: tuple[int, int]
) -> NDArray[np.int16]:
    """The band search written out per pixel: for each shift j the block sum of
    |ref(x') − other(x' − centre(x') − j)| over the window's x' (reflected at the image's
    border, as OpenCV's box filter does), and the first shift with the least cost within
    ``d_range``."""
    h, w = ref.shape
    r = window // 2
    ys, xs = np.mgrid[0:h, 0:w]
    best_cost = np.full((h, w), np.inf)
    best = np.zeros((h, w), dtype=np.int16)
    for j in range(-half, half + 1):
        cols = np.clip(xs - centre - j, 0, w - 1)
        diff = np.abs(ref.astype(np.int64) - other[ys, cols].astype(np.int64))
        padded = np.pad(diff, r, mode="reflect")
        cost = sum(
            padded[r + dy : r + dy + h, r + dx : r + dx + w]
            for dy in range(-r, r + 1)
            for dx in range(-r, r + 1)
        )
        d = centre + j
        better = (cost < best_cost) & (d >= d_range[0]) & (d <= d_range[1])
        best_cost = np.where(better, cost, best_cost)
        best = np.where(better, d, best).astype(np.int16)
    return best


@pytest.mark.parametrize("window", [5, 7])
def test_band_search_is_a_brute_force_block_matcher(window: int) -> None:
    left, right = shifted_pair(12.0, h=60, w=90, noise=2.0)
    ref = np.clip(normalise_contrast(left) * 32 + 128, 0, 255).round().astype(np.uint8)
    other = np.clip(normalise_contrast(right) * 32 + 128, 0, 255).round().astype(np.uint8)
    centre = np.full(ref.shape, 11, dtype=np.int16)  # a field one pixel off either way
    centre[:, 45:] = 13
    got = search_rows(
        ref,
        other,
        of_rows([Hypothesis(centre, 2)]),
        (0, 60),
        window=window,
        d_range=(0, 40),
        invalid=-16,
        parabola=False,
    )
    want = _brute_force(ref, other, centre, 2, window, (0, 40))
    # Where every try's block lies in the other image (left of it, the matches are outside the
    # image and the gathers clamp differently; the unmatched band covers those columns).
    inside = np.s_[:, 14 + 2 + window // 2 :]
    np.testing.assert_array_equal(got[inside], want[inside] * 16)
    assert np.mean(got[10:-10, 20:] == 12 * 16) > 0.9, "the band holds the truth: found"


def test_band_layout_does_not_change_the_result() -> None:
    left, right = shifted_pair(17.6, h=150, w=120, noise=2.0)
    raw = StereoMatcher(StereoParams(coarse_to_fine=True, disparity_range=64, subpixel=False)).compute(
        left, right
    )
    from rig.band_search import quantise_normalised

    ref, other = (quantise_normalised(normalise_contrast(i)) for i in (left, right))
    coarse = np.where(raw.left > 0, raw.left / 32.0, np.nan).astype(np.float32)[::2, ::2]
    hyps = hypotheses(coarse, left.shape, 2)
    kwargs = {"window": 7, "d_range": (0, 63), "invalid": -16, "parabola": True}
    whole = search_rows(ref, other, of_rows(hyps), (0, 150), **kwargs)  # type: ignore[arg-type]
    # Each band's hypotheses made from its own coarse rows are the whole image's.
    by_band = band_hypotheses(coarse, 120, 150, 2)
    inward = (band_hypotheses(coarse, 120, 150, 2, 2), of_rows(hypotheses(coarse, left.shape, 2, 2)))
    for a, b in ((0, 150), (0, 7), (3, 60), (61, 63), (100, 150)):
        for bands, whole_image in ((by_band, of_rows(hyps)), inward):
            for mine, theirs in zip(bands(a, b), whole_image(a, b), strict=True):
                np.testing.assert_array_equal(mine.centre, theirs.centre)
    for step in (1, 7, 50):
        parts = [
            search_rows(ref, other, by_band, (r, min(150, r + step)), **kwargs) for r in range(0, 150, step)
        ]  # type: ignore[arg-type]
        np.testing.assert_array_equal(np.concatenate(parts), whole)


def test_the_refinement_gets_the_normalisation_it_would_make() -> None:
    left, right = shifted_pair(20.4, noise=2.0)
    raw = StereoMatcher(StereoParams(coarse_to_fine=True, disparity_range=64)).compute(left, right)
    assert raw.normalised is not None
    np.testing.assert_array_equal(raw.normalised[0], normalise_contrast(left))
    np.testing.assert_array_equal(raw.normalised[1], normalise_contrast(right))


@pytest.mark.parametrize(
    ("disparities", "scale", "coarse_range"),
    [(64, 2, 32), (96, 2, 48), (128, 2, 64), (192, 4, 48), (256, 4, 64)],  # (without "beyond")
)
def test_the_coarse_level(disparities: int, scale: int, coarse_range: int) -> None:
    p = StereoParams(coarse_to_fine=True, disparity_range=disparities)
    coarse = p.coarse_level()
    _, core, beyond = p.coarse_span()
    assert p.coarse_factor == scale and core == coarse_range and coarse.disparity_range == core + beyond
    assert beyond == 16 and beyond >= coarse_range / 4
    assert not coarse.coarse_to_fine and coarse.min_disparity == 0
    # It covers the range, and leaves the same columns unmatched as the exact search.
    assert scale * coarse.disparity_range >= disparities
    assert p.blind_band_px == StereoParams(disparity_range=disparities, coarse_to_fine=False).blind_band_px
    # A stiffer smoothness penalty, within SGBM's 16-bit path costs.
    assert coarse.penalties()[1] == 4 * p.penalties()[1]
    assert StereoParams(coarse_to_fine=True, disparity_range=96, coarse_scale=4).coarse_factor == 4
    assert StereoParams(coarse_to_fine=False).coarse_factor == 1
    assert StereoParams(stereo_algorithm=0).coarse_factor == 1, "block matching searches the whole range"
    # A range that is no multiple of 16 coarse px: its unmatched band is the coarse level's.
    odd = StereoParams(coarse_to_fine=True, disparity_range=112)
    assert odd.coarse_level().disparity_range == 64 + 16 and odd.blind_band_px == 128


@pytest.mark.parametrize("subpixel", [True, False])
def test_nothing_outside_the_range(subpixel: bool) -> None:
    # The hypotheses near the range's ends reach past them: the band search keeps to the range.
    # A surface nearer than the range reaches (but within the coarse level's search beyond it,
    # 16 coarse px) is found too near and left without depth, not matched wrongly within the
    # range (the exact search places 23 % of this one within the range, far too far).
    for d in (1.6, 30.6, 44.0):
        left, right = shifted_pair(d, w=240)
        params = StereoParams(coarse_to_fine=True, disparity_range=32, min_disparity=1, subpixel=subpixel)
        res = StereoMatcher(params).match(left, right)
        found = res.disparity[res.valid]
        assert found.size == 0 or (found.min() >= 0.5 and found.max() <= 32.5), d
        assert found.size > 0.3 * left.size if d < 32 else found.size < 0.005 * left.size, d
    exact = StereoMatcher(StereoParams(disparity_range=32, min_disparity=1, coarse_to_fine=False))
    assert exact.match(left, right).valid[ROI].mean() > 0.1
