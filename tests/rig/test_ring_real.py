"""The real ring of ../shared/data/ring_sweepnet_indoor (four ~220° fisheyes, 0.3 m baselines,
``RIG_SHARED_DATA``; no ground truth): the loader's conventions checked on the images (every
adjacent pair's features land on the same rows, the inverse pose convention finds nothing),
pairs from geometry, the rig.yaml round trip, and the consistency measure on one frame through
today's default pipeline. ``pytest -s`` prints the figures; ``python -m bench.ring_consistency``
prints all three frames' (docs/ring.md)."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.formats import load_rig
from calibration.geometry import invert_transform
from calibration.rig import Rig
from rig.evaluate.consistency_study import consistency_study
from rig.rectification import EpipolarViews, RayMatches, match_pair, vertical_disparity
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from rig.ring import adjacent_pairs
from tests.conftest import shared_file
from tests.helpers.ring import RING_DIR, RealRing, load_ring, write_ring

pytestmark = pytest.mark.slow

RING = [("cam1", "cam2"), ("cam2", "cam3"), ("cam3", "cam4"), ("cam4", "cam1")]


@pytest.fixture(scope="module")
def ring() -> RealRing:
    return load_ring(shared_file(RING_DIR))


def _rows(rig: Rig, ring: RealRing, a: str, b: str) -> tuple[int, float | None]:
    """Matches over the three frames and the median |vertical disparity| (px at 5.585 px/deg)."""
    views = EpipolarViews(rig, a, b, scale=0.5)
    matches = RayMatches.concat([match_pair(views, f[a], f[b], frame=i) for i, f in enumerate(ring.frames)])
    vd = vertical_disparity(
        design_rectified_pair(rig, RectifiedPairConfig(left=a, right=b)), matches.left, matches.right
    )
    return vd.count, vd.p50_px


def test_the_poses_rectify_every_adjacent_pair(ring: RealRing) -> None:
    assert adjacent_pairs(ring.rig) == RING
    for a, b in RING:
        baseline = ring.rig.baseline(a, b)
        count, p50 = _rows(ring.rig, ring, a, b)
        print(
            f"\nring {a}|{b}: baseline {baseline:.3f} m, {count} matches, "
            f"median |vertical disparity| {p50:.2f} px"
        )
        assert 0.29 < baseline < 0.32
        assert count >= 250 and p50 is not None and p50 < 2.5  # measured 336-540 matches, 1.07-1.73 px
    # Read the other way round (P_cam = R P_rig + t), the views of a pair no longer look alike.
    inverse = Rig(dict(ring.rig.cameras), {n: invert_transform(T) for n, T in ring.rig.T_rig_cam.items()})
    count, p50 = _rows(inverse, ring, "cam1", "cam2")
    assert count < 60 and p50 is None  # measured 25 matches: "not enough matches"


def test_the_ring_round_trips_through_rig_yaml(ring: RealRing, tmp_path: object) -> None:
    from pathlib import Path

    path = write_ring(ring, Path(str(tmp_path)))
    back = load_rig(path)
    assert back.names == list(ring.rig.names)
    for n in back.names:
        assert back.cameras[n].to_dict() == ring.rig.cameras[n].to_dict()
        assert np.array_equal(back.T_rig_cam[n], ring.rig.T_rig_cam[n])
        assert back.cameras[n].name == "scaramuzza" and back.cameras[n].fov_deg == pytest.approx(
            225.83, abs=0.01
        )
    assert len(list(path.parent.glob("cam*/0000*.png"))) == 12


def test_the_real_ring_disagrees_with_itself_within_a_sane_band(ring: RealRing, lut_cache: object) -> None:
    study = consistency_study(ring.rig, ring.frames[:1], cache_dir=str(lut_cache), keep_ranges=True)
    assert [p.names for p in study.pairs] == RING
    print()
    for p in study.pairs:
        r = p.ranges[0].range
        q25, q50, q75 = np.nanpercentile(r, [25, 50, 75])
        print(
            f"ring {p.label}: coverage {p.coverage[0]:.3f}, range quartiles {q25:.2f} {q50:.2f} {q75:.2f} m"
        )
        assert 0.15 < p.coverage[0] < 0.6  # measured 0.29-0.34
        assert 1.0 < q50 < 5.0 and q75 < 10.0  # an office: measured medians 1.6-2.4 m
    for c in study.couples:
        f = c.figures
        print(
            f"ring {c.couple.label}: both {f.both_share:.3f}, median |e| {f.median_abs:.4f}, signed "
            f"{f.median_signed:+.4f}, within 3 % {f.within_3:.3f}, 10 % {f.within_10:.3f}, "
            f"median |dd| {f.median_abs_px:.2f} px"
        )
        values = [f.both_share, f.median_abs, f.median_signed, f.within_3, f.within_10, f.median_abs_px]
        assert np.isfinite(values).all() and f.both > 10000
        # Far from the renders' 0.8 %, far from noise: what the real-lens work has to drive down.
        assert 0.02 < f.median_abs < 0.25 and abs(f.median_signed) < 0.1
        assert 0.5 < f.median_abs_px < 6.0
