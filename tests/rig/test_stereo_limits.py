"""What the matcher can really do: SGBM keeps its path costs in 16 bits, and some combinations of
window and penalties inside each field's own bounds saturate them, after which nearly every
disparity is wrong while most pixels still look valid. StereoParams refuses exactly those
combinations (P2 + 16·window² above 32767); on a rendered plane every combination it accepts
matches, and the ones it refuses, run on OpenCV anyway, do not."""

from __future__ import annotations

import functools
import itertools

import numpy as np
import pytest
from pydantic import ValidationError

from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPairConfig
from rig.stereo import COST_PER_WINDOW_PIXEL, MAX_PATH_COST, StereoMatcher, StereoParams
from tests.helpers.shots import plane_shot

VPC = RectifiedPairConfig(width=320, height=240)
BARE = {"disparity_range": 64, "lr_check": False, "subpixel": False, "median": 0, "speckle_size": 0}
MODES = ("sgbm", "3way", "hh")
WINDOWS = (7, 15, 21, 25, 27, 29, 31)
P2S = (0, 16000, 30000, 32000, 40000)  # 0: the default 32·w²


@functools.lru_cache(maxsize=1)
def _pair(cache: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    shot = plane_shot(5.0, scale=0.5, vpc=VPC)
    left, right = DepthPipeline(shot.rig, VPC, cache_dir=cache, tune_malloc=False).remap(
        shot.left, shot.right
    )
    return left, right, shot.disparity


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return _pair(str(tmp_path_factory.mktemp("lut")))


def _scores(params: StereoParams, pair: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[float, float]:
    left, right, truth = pair
    m = StereoMatcher(params).match(left, right)
    ok = m.valid & np.isfinite(truth)
    good = np.abs(m.disparity[ok] - truth[ok]) < 1.0
    return float(m.valid.mean()), float(good.mean()) if good.size else 0.0


@pytest.mark.parametrize("coarse_to_fine", [True, False], ids=["coarse-to-fine", "exact"])
def test_every_accepted_combination_matches_and_every_refused_one_fails(
    pair: tuple[np.ndarray, np.ndarray, np.ndarray], coarse_to_fine: bool
) -> None:
    # The coarse-to-fine search's coarse level runs a stiffer P2 (StereoParams.coarse_level),
    # within the same bound.
    accepted, refused = [], []
    for mode, w, p2 in itertools.product(MODES, WINDOWS, P2S):
        fields = {
            **BARE,
            "sgbm_mode": mode,
            "correlation_window_size": w,
            "P2": float(p2),
            "coarse_to_fine": coarse_to_fine,
        }
        try:
            params = StereoParams(**fields)
        except ValidationError as err:
            assert "overflows SGBM's 16-bit path costs" in str(err)
            # What OpenCV does with them when nothing stops it.
            refused.append((mode, w, p2, _scores(StereoParams.model_construct(**fields), pair)))
            continue
        accepted.append((mode, w, p2, _scores(params, pair)))
    print(f"\n{len(accepted)} accepted, {len(refused)} refused")
    for mode, w, p2, (valid, good) in refused:
        print(f"refused {mode} w={w} P2={p2 or 'default'}: valid {valid:.2f}, right {good:.2f}")
    assert len(accepted) >= 30 and len(refused) >= 30
    bad = [(m, w, p2, s) for m, w, p2, s in accepted if s[0] < 0.5 or s[1] < 0.9]
    assert not bad, f"accepted but wrong: {bad}"
    collapsed = [r for r in refused if r[3][1] < 0.5]
    assert len(collapsed) >= 0.8 * len(refused)
    if not coarse_to_fine:
        # Refused: fewer right disparities than any accepted combination gives (most refused ones
        # none at all; at the edge, a 27 px window with the default penalties, a tenth fewer).
        # (The coarse-to-fine search's full resolution has no path costs: a few refused ones at
        # the edge still match there.)
        least_accepted = min(valid * good for *_, (valid, good) in accepted)
        assert all(valid * good < least_accepted for *_, (valid, good) in refused)


def test_the_rule_is_stated_once_and_says_how_to_fix_it() -> None:
    with pytest.raises(ValidationError) as err:
        StereoParams(correlation_window_size=27)
    text = str(err.value)
    p2 = 32 * 27 * 27
    assert f"P2 {p2}" in text and f"P2 at most {MAX_PATH_COST - COST_PER_WINDOW_PIXEL * 27 * 27}" in text
    assert "a window of at most 25 with the default penalties" in text
    StereoParams(correlation_window_size=25)  # the largest with the default penalties
    StereoParams(stereo_algorithm=0, correlation_window_size=31)  # block matching has no path costs
