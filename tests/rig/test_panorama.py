"""The 360° range panorama (rig.panorama): its frame, one pair's range moved into it against the
renderer's exact range along the panorama's own rays (parallax between the pair's camera and the
panorama's origin is exact, not assumed away), and the fusion's rules: agreeing pairs averaged
by their predicted errors, disagreeing ones flagged and never averaged, nothing invented."""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np
import pytest

from calibration.geometry import make_transform
from rig.field import pixel_solid_angles
from rig.panorama import DISAGREE, FUSED, PairOutput, PanoramaSpec, fuse_panorama, lenses_seeing
from rig.pipeline import DepthFrame, DepthPipeline
from rig.rectified import RectifiedPairConfig
from rig.sim import room_scene
from rig.sim.render import render_range
from rig.stereo import StereoParams
from tests.helpers.shots import prototype_rig, render_for_pair

STEREO = StereoParams(disparity_range=64)
LATLON = RectifiedPairConfig(projection="latlon", px_per_deg=2.8)  # half the default: the half-size rig
T_WORLD_RIG = make_transform(np.eye(3), [0.3, 0.0, -0.2])


@functools.lru_cache(maxsize=1)
def _room(cache: str) -> tuple[DepthPipeline, DepthFrame]:
    rig = prototype_rig(0.5)
    pipe = DepthPipeline(rig, LATLON, STEREO, cache_dir=cache, tune_malloc=False)
    scene = room_scene(0)
    left, right = (
        render_for_pair(scene, rig, n, pipe.pair, T_WORLD_RIG, 2, 0.75, 0.35, i)
        for i, n in enumerate(("left", "right"))
    )
    return pipe, pipe.process(left, right)


@pytest.fixture(scope="module")
def room(tmp_path_factory: pytest.TempPathFactory) -> tuple[DepthPipeline, DepthFrame]:
    return _room(str(tmp_path_factory.mktemp("lut")))


def _pair_range(pipe: DepthPipeline, frame: DepthFrame, name: str = "left-right") -> PairOutput:
    return PairOutput(
        name, pipe.pair, frame.range, frame.disparity, frame.confidence, pipe.stereo.confidence_sigma
    )


def test_the_panorama_frame_of_a_two_camera_rig_is_the_rig_frame() -> None:
    rig = prototype_rig(0.5)
    spec = PanoramaSpec.for_rig(rig, 2.0)
    # Optical axes in the rig's x-z plane: down is the rig's y, forward its z, the origin midway.
    assert np.allclose(spec.R_rig_pano, np.eye(3), atol=1e-9)
    assert np.allclose(spec.origin, (rig.center("left") + rig.center("right")) / 2)
    assert (spec.camera.width, spec.camera.height) == (720, 360)
    doc = spec.as_json(["left-right"])
    assert doc["projection"] == "equirect" and doc["pairs"] == ["left-right"] and doc["px_per_deg"] == 2.0
    seen = lenses_seeing(rig, spec)
    # Two 190° lenses 90° apart: some directions by both, some by one, the back by none.
    assert {0, 1, 2} <= set(np.unique(seen).tolist())


def test_one_pair_in_the_panorama_is_as_exact_as_the_pair(room: tuple[DepthPipeline, DepthFrame]) -> None:
    """Moved into the panorama (read along its rays from the origin, not the pair's camera), a
    pair's range is as close to the truth as it was in its own view, over as much solid angle."""
    pipe, frame = room
    scene = room_scene(0)
    spec = PanoramaSpec.for_rig(pipe.rig, 2.0)
    pano = fuse_panorama(spec, [_pair_range(pipe, frame)])
    truth, _ = render_range(scene, spec.camera, T_WORLD_RIG @ spec.T_rig_pano)
    own_truth, _ = render_range(scene, pipe.pair.camera, T_WORLD_RIG @ pipe.pair.T_rig_rect["left"])

    def within(rng: np.ndarray, exact: np.ndarray, solid: np.ndarray) -> tuple[float, float]:
        ok = np.isfinite(rng) & np.isfinite(exact)
        close = np.abs(rng[ok] / exact[ok] - 1.0) < 0.03
        return float(solid[ok][close].sum() / solid[ok].sum()), float(solid[np.isfinite(rng)].sum())

    pano_within, pano_sr = within(pano.range, truth, pixel_solid_angles(spec.camera))
    pair_within, pair_sr = within(frame.range, own_truth, pixel_solid_angles(pipe.pair.camera))
    print(f"\nwithin 3 % of the truth: the pair {100 * pair_within:.1f} % over {pair_sr:.3f} sr, "
          f"in the panorama {100 * pano_within:.1f} % over {pano_sr:.3f} sr")  # fmt: skip
    assert pano_within > pair_within - 0.01 and pair_within > 0.7
    assert 0.97 < pano_sr / pair_sr < 1.03
    assert (pano.samples <= 1).all() and not (pano.flags & (FUSED | DISAGREE)).any()
    has = np.isfinite(pano.range)
    assert (pano.source[has] == 0).all() and (pano.source[~has] == -1).all()
    assert np.all(pano.sigma[has] > 0)


def test_agreeing_pairs_are_averaged_by_their_predicted_errors(
    room: tuple[DepthPipeline, DepthFrame],
) -> None:
    pipe, frame = room
    spec = PanoramaSpec.for_rig(pipe.rig, 2.0)
    one = _pair_range(pipe, frame, "a")
    # The same surfaces by a second, less certain pair, 0.5 % further: within the predicted error.
    other = replace(one, name="b", range=frame.range * np.float32(1.005), confidence=frame.confidence**4)
    pano = fuse_panorama(spec, [one, other])
    alone = fuse_panorama(spec, [one])
    both = (pano.samples == 2) & ((pano.flags & FUSED) > 0)
    assert both.mean() > 0.05
    ratio = pano.range[both] / alone.range[both]
    # Inverse-variance weights: between the two, much nearer to the more certain pair's value
    # (a few pixels at depth edges read another surface point through the other range).
    between = (ratio >= 1.0 - 1e-4) & (ratio <= 1.005 + 1e-4)
    assert between.mean() > 0.99 and np.median(ratio) < 1.0025
    assert (pano.sigma[both] < alone.sigma[both] + 1e-7).all()


def test_disagreeing_pairs_are_flagged_and_never_averaged(room: tuple[DepthPipeline, DepthFrame]) -> None:
    pipe, frame = room
    spec = PanoramaSpec.for_rig(pipe.rig, 2.0)
    good = _pair_range(pipe, frame, "good")
    # A pair 20 % off (a wrong calibration, say), as certain as the good one in disparity.
    wrong = replace(good, name="wrong", range=frame.range * np.float32(1.2))
    pano = fuse_panorama(spec, [good, wrong])
    alone = fuse_panorama(spec, [good])
    both = pano.samples == 2
    flagged = (pano.flags & DISAGREE) > 0
    # Beyond 3 combined predicted errors (the wrong pair's is 1.2 times the good one's) they
    # disagree; well within, they agree: near ranges (large disparities) are told apart,
    # far ones, whose predicted error covers 20 %, are not.
    limit = 3.0 * np.sqrt(1.0 + 1.2**2) * alone.sigma
    off = 0.2 * alone.range
    clear = both & (off > 1.1 * limit)
    unclear = both & (off < 0.9 * limit)
    assert clear.sum() > 1000 and flagged[clear].mean() > 0.99
    assert unclear.sum() > 100 and flagged[unclear].mean() < 0.01
    # The best pair's range stands, unaveraged, where they disagree: mostly the good one's.
    d = both & flagged
    wrong_alone = fuse_panorama(spec, [wrong])
    best = np.where(pano.source == 0, alone.range, wrong_alone.range)
    assert np.array_equal(pano.range[d], best[d]) and (pano.source[d] == 0).mean() > 0.95
    assert not ((pano.flags & FUSED) > 0)[d].any()
