"""The rectification measure and refinement on real fisheye images: sourishg's 29 stereo pairs
(960x600, an office with a person holding a chessboard; ``RIG_SHARED_DATA``). The pair is
calibrated from the boards of every other pair (what ``rig calibrate stereo`` does), then the
office scene of all 29 pairs measures and refines it. There is no ground truth: the checks are
that the scene's vertical disparity drops, that a calibration turned 0.7° away converges to the
same answer, and that the moving person and board are rejected as outliers. ``pytest -s``
prints the figures docs/rectification.md quotes."""

from __future__ import annotations

import functools
import re
from pathlib import Path

import cv2
import pytest

from calibration import board_object_points, calibrate_stereo, detect_chessboard_files
from calibration.rig import Rig
from rig.rectification import EpipolarViews, RayMatches, match_pair, refine_rig
from rig.rectified import RectifiedPairConfig
from tests.conftest import shared_file
from tests.rig.rectification_renders import perturbed, relative_rotation_error_deg

pytestmark = pytest.mark.slow


def _pairs(folder: Path) -> tuple[list[str], list[str]]:
    def number(p: Path) -> int:
        return int(re.findall(r"(\d+)\.jpg$", p.name)[0])

    left = sorted(folder.glob("left*.jpg"), key=number)
    right = sorted(folder.glob("right*.jpg"), key=number)
    return [str(p) for p in left], [str(p) for p in right]


@functools.cache
def _calibrated_and_matches() -> tuple[Rig, RayMatches]:
    left, right = _pairs(shared_file("fisheye_stereo_sourishg/imgs"))
    assert len(left) == len(right) == 29
    found = [detect_chessboard_files(paths[::2], (9, 6)) for paths in (left, right)]
    obj = board_object_points(9, 6, 0.02423)
    stereo = calibrate_stereo(
        "kannala_brandt", [obj] * len(found[0]), [d.corners for d in found[0]], [d.corners for d in found[1]],
        (960, 600),
    )  # fmt: skip
    views = EpipolarViews(stereo.rig)
    matches = RayMatches.concat(
        [
            match_pair(
                views, cv2.imread(a, cv2.IMREAD_GRAYSCALE), cv2.imread(b, cv2.IMREAD_GRAYSCALE), frame=i
            )
            for i, (a, b) in enumerate(zip(left, right, strict=True))
        ]
    )
    return stereo.rig, matches


def test_real_pairs_scene_refinement_lowers_the_vertical_disparity() -> None:
    rig, matches = _calibrated_and_matches()
    vpc = RectifiedPairConfig()
    result = refine_rig(rig, matches, vpc)
    fit = result.fit
    print(
        f"\nsourishg, board-calibrated extrinsics: vertical disparity p50 {result.before.p50_px:.2f} px "
        f"(median {result.before.median_px:+.2f} px), p95 {result.before.p95_px:.2f} px; refined from the "
        f"office ({fit.n_inliers} of {len(matches)} matches, 29 pairs): correction {fit.angle_deg:.3f}° ± "
        f"{fit.angle_sigma_deg:.3f}° {fit.rotation_deg.round(3).tolist()}; p50 {result.after.p50_px:.2f} px, "
        f"p95 {result.after.p95_px:.2f} px"
    )
    assert result.before.p50_px is not None and result.after.p50_px is not None
    assert result.after.p50_px < 0.6 * result.before.p50_px and result.after.p50_px < 0.3
    assert fit.angle_deg > 10 * fit.angle_sigma_deg
    # The person and the board move between pairs, and mismatches happen: not all matches agree.
    assert 0.5 < fit.n_inliers / len(matches) < 0.99
    # A calibration turned 0.7° away finds the same extrinsics.
    again = refine_rig(perturbed(rig, (0.5, -0.3, 0.4)), matches, vpc)
    assert again.before.p50_px is not None and again.before.p50_px > 1.5
    assert relative_rotation_error_deg(again.rig_after, result.rig_after) < 0.01
