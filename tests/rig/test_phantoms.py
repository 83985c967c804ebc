"""Phantom obstacles with the stereo defaults, measured on renders with exact ground truth.

The scenes of :mod:`rig.evaluate.phantoms` that matter most, on the 640×480 pinhole pair (where
the defaults were chosen) and on the default lat-lon pair: the
README's walkthrough room where a repetitive printed wall ~6.8 m away came out at 0.23 m on a few
% of the valid pixels, a wall of bars, a low-texture wall and a wall 0.3 m ahead (a real near
obstacle must not be pushed away by the cure). The defaults (the exact search) and the defaults
with the coarse-to-fine search (``coarse_to_fine: true``; on the lat-lon pair also with its
confirmed coarse level, ``coarse_confirm: true``). ``pytest -s`` prints the figures; the table over
every scene and setting is ``python -m bench.phantoms`` (docs/stereo.md).

Renders: the prototype's honest lens (:data:`LENS`, blur growing to the rim, rim darkening,
per-camera exposure, sensor noise; docs/evaluation.md, "The honest renderer"), the renders the
product's figures are published for. Through it the pinhole pair gives phantoms on the bars
(0.37 %, over the 0.1 % bar) where the ideal lens gives none: a known limit of today's matcher,
asserted as measured; the default lat-lon pair stays under the bar on every scene.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calibration.rig import Rig
from rig.evaluate.phantoms import PHANTOM_VPC, PhantomShot, PhantomStats, phantom_stats, render_phantom_shot
from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams

pytestmark = pytest.mark.slow

SCENES = ("room-walk-1", "stripes", "low-texture", "near-wall")
LENS = "honest"
# The defaults until the phantoms were measured (the exact search, the only one then; the matcher
# saw the images as they are), and today's defaults with the coarse-to-fine search.
BEFORE = StereoParams(disparity_range=128, lr_check=False, match_normalise_window=0, coarse_to_fine=False)
C2F = StereoParams(coarse_to_fine=True)
#: The exact search with its left-right check's second search at full resolution (the default
#: until the half-resolution check, ``lr_check_scale: 2``).
FULL_CHECK = StereoParams(lr_check_scale=1)
#: The coarse-to-fine search with its coarse level confirmed (``coarse_confirm``).
CONFIRMED = StereoParams(coarse_to_fine=True, coarse_confirm=True)
#: The coarse-to-fine search (an option) on the default lat-lon pair through the honest lens,
#: with the matcher's normalised input, as measured: over the 0.1 % phantom bar on the bars and the
#: low-texture wall (the exact search: under it), a known regression (docs/stereo.md).
C2F_LATLON_PHANTOMS = {"stripes": 0.0096, "low-texture": 0.0045}
LOST_C2F = 0.02


def measured_rig() -> Rig:
    return render_phantom_shot(SCENES[0], lens=LENS).rig


@pytest.fixture(scope="module")
def shots() -> dict[str, PhantomShot]:
    return {name: render_phantom_shot(name, lens=LENS) for name in SCENES}


@pytest.fixture(scope="module")
def measured(
    shots: dict[str, PhantomShot], tmp_path_factory: pytest.TempPathFactory
) -> dict[str, dict[str, PhantomStats]]:
    """Stats per setting ("defaults", "before") and scene."""
    pipe = DepthPipeline(shots[SCENES[0]].rig, PHANTOM_VPC, cache_dir=tmp_path_factory.mktemp("lut"))
    out: dict[str, dict[str, PhantomStats]] = {}
    for label, params in (("defaults", StereoParams()), ("coarse-to-fine", C2F), ("before", BEFORE)):
        pipe.apply(stereo=params)
        out[label] = {}
        for name, shot in shots.items():
            frame = pipe.process(shot.left, shot.right)
            out[label][name] = phantom_stats(frame.depth, frame.valid, shot.truth)
    print("\nphantom % / valid % / lost %, VPC 640x480")
    for label, stats in out.items():
        cells = [
            f"{n} {100 * s.phantom_rate:.3f} / {100 * s.valid_fraction:.1f} / {100 * s.lost_rate:.2f}"
            for n, s in stats.items()
        ]
        print(f"{label:14s}", " | ".join(cells))
    return out


@pytest.fixture(scope="module")
def latlon_measured(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, PhantomStats]]:
    """Stats per search (the default exact one, the coarse-to-fine) and scene with the stereo defaults
    on the default lat-lon pair (its field takes in the matcher's unmatched columns, as the
    pipeline's does: the same for both searches)."""
    params = StereoParams()
    assert params.blind_band_px == C2F.blind_band_px
    shots = {
        n: render_phantom_shot(n, vpc=RectifiedPairConfig(), blind_band_px=params.blind_band_px, lens=LENS)
        for n in SCENES
    }
    first = shots[SCENES[0]]
    pipe = DepthPipeline(
        first.rig, RectifiedPairConfig(), params, cache_dir=tmp_path_factory.mktemp("lut-latlon")
    )
    assert pipe.pair.projection == "latlon" and pipe.pair.camera.width == first.pair.camera.width
    out: dict[str, dict[str, PhantomStats]] = {}
    print("\nphantom % / valid % / lost %, the default lat-lon pair (valid: of every pixel with a surface)")
    searches = {"defaults": params, "full check": FULL_CHECK, "coarse-to-fine": C2F, "confirmed": CONFIRMED}
    for label, stereo in searches.items():
        pipe.apply(stereo=stereo)
        out[label] = {}
        for name, shot in shots.items():
            frame = pipe.process(shot.left, shot.right)
            out[label][name] = phantom_stats(frame.range, frame.valid, shot.truth)
        cells = [
            f"{n} {100 * s.phantom_rate:.3f} / {100 * s.valid_fraction:.1f} / {100 * s.lost_rate:.2f}"
            for n, s in out[label].items()
        ]
        print(f"{label:14s}", " | ".join(cells))
    return out


@pytest.mark.parametrize("search", ["defaults", "full check", "coarse-to-fine", "confirmed"])
@pytest.mark.parametrize("scene", SCENES)
def test_defaults_keep_phantoms_under_a_thousandth_on_the_latlon_pair(
    latlon_measured: dict[str, dict[str, PhantomStats]], scene: str, search: str
) -> None:
    rate = latlon_measured[search][scene].phantom_rate
    if search == "coarse-to-fine" and scene in C2F_LATLON_PHANTOMS:
        assert rate == pytest.approx(C2F_LATLON_PHANTOMS[scene], rel=0.3)
    else:
        assert rate < 0.001


def test_the_latlon_pair_places_the_far_side_of_the_bars_too_far(
    latlon_measured: dict[str, dict[str, PhantomStats]],
) -> None:
    """A known limit of the exact search with its full-resolution left-right check
    (docs/stereo.md): where the bars wall turns away from the rig (azimuth −50° to −20°, beyond
    the pinhole pair's view) their period in the image comes close to the disparity, and both
    views lock onto the neighbouring bar: the wall comes out 4–10× too far (on 22–25 % of its
    valid pixels through the honest lens with the matcher's normalised input, 30 % without it,
    20 % through the ideal one). The check at half resolution (the default) searches with the
    coarse level's stiffer smoothness penalty, which keeps that wall on one period, so it
    rejects the wrong one (0.04 %); so does the coarse-to-fine search's coarse level
    (LOST_C2F). The other scenes place little that far."""
    assert latlon_measured["full check"]["stripes"].lost_rate == pytest.approx(0.24, abs=0.04)
    assert latlon_measured["defaults"]["stripes"].lost_rate < 0.005
    assert latlon_measured["coarse-to-fine"]["stripes"].lost_rate < LOST_C2F
    for search in ("defaults", "full check", "coarse-to-fine"):
        for scene in ("room-walk-1", "low-texture", "near-wall"):
            # (the coarse-to-fine search: 1.25 % on the low-texture wall)
            assert latlon_measured[search][scene].lost_rate < 0.015, (search, scene)


def test_the_walkthrough_wall_gave_phantoms_before(measured: dict[str, dict[str, PhantomStats]]) -> None:
    before = measured["before"]["room-walk-1"]
    assert before.phantom_rate == pytest.approx(0.0347, abs=0.006)
    assert measured["before"]["low-texture"].phantom_rate > 0.01


@pytest.mark.parametrize("search", ["defaults", "coarse-to-fine"])
@pytest.mark.parametrize("scene", ("room-walk-1", "low-texture", "near-wall"))
def test_defaults_keep_phantoms_under_a_thousandth(
    measured: dict[str, dict[str, PhantomStats]], scene: str, search: str
) -> None:
    assert measured[search][scene].phantom_rate < 0.001


def test_the_bars_give_no_phantoms_through_either_lens(
    measured: dict[str, dict[str, PhantomStats]], tmp_path: Path
) -> None:
    """Through the honest lens the bars gave 0.37 % phantoms on the pinhole pair when the matcher
    compared the views as they are (their brightness differs); with its normalised input
    (rig.match_input) none, as through the ideal lens."""
    assert measured["defaults"]["stripes"].phantom_rate < 0.001
    as_they_are = DepthPipeline(
        measured_rig(),
        PHANTOM_VPC,
        StereoParams(match_normalise_window=0, coarse_to_fine=False),
        cache_dir=tmp_path / "raw",
    )
    shot = render_phantom_shot("stripes", lens=LENS)
    raw = as_they_are.process(shot.left, shot.right)
    assert phantom_stats(raw.depth, raw.valid, shot.truth).phantom_rate > 0.002
    ideal = render_phantom_shot("stripes", lens="ideal")
    pipe = DepthPipeline(ideal.rig, PHANTOM_VPC, cache_dir=tmp_path)
    frame = pipe.process(ideal.left, ideal.right)
    assert phantom_stats(frame.depth, frame.valid, ideal.truth).phantom_rate < 0.001


def test_defaults_lose_no_valid_pixels_and_no_near_obstacle(
    measured: dict[str, dict[str, PhantomStats]],
) -> None:
    now, before = measured["defaults"], measured["before"]
    # Fewer columns lost to the disparity range outweigh what the left-right check removes.
    for scene in ("room-walk-1", "low-texture", "near-wall"):
        assert now[scene].valid_fraction > before[scene].valid_fraction - 0.03, scene
    # On the bars the normalised input more than makes up what the left-right check removes.
    assert now["stripes"].valid_fraction > before["stripes"].valid_fraction + 0.1
    assert now["room-walk-1"].valid_fraction == pytest.approx(0.845, abs=0.02)
    # The wall 0.3 m ahead (disparity 77 px) stays within reach: valid, and placed far on under
    # 1 % of it (0.7 % through the honest lens, none through the ideal one).
    near = now["near-wall"]
    assert near.valid_fraction > 0.75 and near.lost_rate < 0.01


def test_stats_count_phantoms_and_lost_surfaces() -> None:
    truth = np.full((2, 3), 4.0, dtype=np.float32)
    truth[1, 2] = np.nan
    depth = np.array([[1.0, 4.1, 9.0], [np.nan, 2.5, 1.0]], dtype=np.float32)
    valid = np.isfinite(depth)
    s = phantom_stats(depth, valid, truth)
    assert (s.surface, s.valid, s.phantoms, s.lost) == (5, 4, 1, 1)
    assert s.phantom_rate == 0.25 and s.valid_fraction == 0.8
    assert (s + s).phantoms == 2


def test_truth_is_the_depth_of_the_nearest_surface(shots: dict[str, PhantomShot]) -> None:
    near = shots["near-wall"]
    c = near.pair.camera
    centre = near.truth[c.height // 2, c.width // 2]
    assert centre == pytest.approx(0.3, abs=0.01)  # the wall's centre is 0.3 m ahead of the rig
    assert np.isfinite(near.truth).all()
