"""The live service's temporal prior (rig.temporal_prior): what did not change keeps its last
search (the coarse-to-fine search's coarse rows, the exact search's whole frame), and an object
entering the view is found in the first frame it is in, with either search.

Renders of the demo room through the half-size prototype (a 320×240 pinhole pair): three frames
of the static room (each with its own sensor noise), then a textured box hanging 0.6 m ahead of
the rig, off to the side, where the room was.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from calibration.geometry import make_transform, rot_y
from calibration.rig import Rig
from rig import temporal_prior
from rig.pipeline import DepthFrame, DepthPipeline, RectifiedImages
from rig.rectified import RectifiedPairConfig
from rig.sim import Scene, make_texture, room_scene
from rig.sim.render import render_range
from rig.sim.scene import rect_from_axes
from rig.stereo import StereoMatcher, StereoParams
from rig.temporal_prior import MAX_AGE, TemporalPrior
from tests.helpers.shots import add_noise, prototype_rig, render_for_pair

VPC = RectifiedPairConfig(width=320, height=240)
STEREO = StereoParams(coarse_to_fine=True, disparity_range=64)
EXACT = STEREO.model_copy(update={"coarse_to_fine": False})
SEARCHES = {"coarse-to-fine": STEREO, "exact": EXACT}
NOISE = 1.5
U8 = NDArray[np.uint8]


def _with_box(scene: Scene) -> Scene:
    """``scene`` and a 0.3 m textured square hanging 0.6 m ahead of the rig, 0.25 m to its right."""
    ex, ey = np.eye(3)[0], np.eye(3)[1]
    texture = make_texture("noise", 5, size_m=0.3).tinted((30, 10, 10), (250, 200, 120))
    box = rect_from_axes([0.25, 0.0, 0.6 - 0.5], ex, ey, (0.3, 0.3), texture, "entering")
    return Scene([*scene.rects, box], {**scene.info, "entering": True})


@functools.lru_cache(maxsize=1)
def _renders(cache: str) -> tuple[DepthPipeline, dict[str, tuple[U8, U8]], dict[str, np.ndarray]]:
    """The pipeline, the noise-free fisheye pair of the room without and with the box, and the
    exact range through the left rectified view of each."""
    rig = prototype_rig(0.5)
    pipe = DepthPipeline(rig, VPC, STEREO, cache_dir=cache, tune_malloc=False)
    T = make_transform(np.eye(3), [0.0, 0.0, -0.5])
    images, truth = {}, {}
    for name, scene in (("room", room_scene(0)), ("box", _with_box(room_scene(0)))):
        images[name] = tuple(render_for_pair(scene, rig, n, pipe.pair, T, 2) for n in ("left", "right"))  # type: ignore[assignment]
        truth[name], _ = render_range(scene, pipe.pair.camera, T @ pipe.pair.T_rig_rect["left"])
    return pipe, images, truth


@pytest.fixture(scope="module")
def renders(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[DepthPipeline, dict[str, tuple[U8, U8]], dict[str, np.ndarray]]:
    return _renders(str(tmp_path_factory.mktemp("lut")))


def _frame(pipe: DepthPipeline, pair: tuple[U8, U8], seed: int, *, prior: bool) -> DepthFrame:
    left, right = (add_noise(img, NOISE, 2 * seed + i) for i, img in enumerate(pair))
    return pipe.postprocess(pipe.match(pipe.rectify(left, right), temporal_prior=prior))


def _searched(pipe: DepthPipeline) -> float:
    return pipe.in_effect.matcher.searched_fraction


@pytest.mark.parametrize("search", SEARCHES)
def test_an_object_entering_the_view_has_depth_in_its_first_frame(
    renders: tuple[DepthPipeline, dict[str, tuple[U8, U8]], dict[str, np.ndarray]], search: str
) -> None:
    pipe, images, truth = renders
    stereo = SEARCHES[search]
    pipe.apply(stereo=stereo)  # a new matcher: an empty history
    static = [_frame(pipe, images["room"], seed, prior=True) for seed in range(3)]
    searched_static = _searched(pipe)
    entering = _frame(pipe, images["box"], 3, prior=True)
    searched_entering = _searched(pipe)
    # The same frame searched whole (no history), by a matcher of its own.
    pipe.apply(stereo=stereo)
    whole = _frame(pipe, images["box"], 3, prior=False)
    box = truth["box"] < truth["room"] - 0.5  # where the box hides the room
    rel = {k: np.abs(f.range / truth["box"] - 1.0) for k, f in (("prior", entering), ("whole", whole))}
    found = {k: float(np.mean(np.nan_to_num(r[box], nan=np.inf) < 0.05)) for k, r in rel.items()}
    # The room behind the box (> 1 m) on the box's pixels: its edges, where blocks straddle it.
    behind = {
        k: float(np.mean(f.valid[box] & (f.range[box] > 1.0)))
        for k, f in (("prior", entering), ("whole", whole))
    }
    print(
        f"\n{search}: box: {box.sum()} px; searched: static frames {searched_static:.3f}, the box's frame "
        f"{searched_entering:.3f}; box within 5 %: prior {found['prior']:.3f}, whole search "
        f"{found['whole']:.3f}; the room's range on it: prior {behind['prior']:.4f}, whole search "
        f"{behind['whole']:.4f}"
    )
    assert box.sum() > 1500, "the box is in view"
    # Static frames: only the bands due for their periodic search (and their neighbours); the
    # exact search nothing.
    assert searched_static < (0.25 if stereo.coarse_to_fine else 0.001)
    # The box's rows were searched again, and its depth is there in its first frame, as in a
    # whole search of that frame; nothing of the room that was there before is left on it.
    assert searched_entering > searched_static
    assert found["prior"] > 0.8 and found["prior"] > found["whole"] - 0.02
    assert behind["prior"] < behind["whole"] + 0.002
    # Elsewhere the history's coarse search serves as well as the frame's own.
    room = ~box & np.isfinite(truth["box"])
    within = [float(np.mean(np.nan_to_num(rel[k][room], nan=np.inf) < 0.03)) for k in ("prior", "whole")]
    assert within[0] > within[1] - 0.005, within
    assert all(f.valid.mean() > 0.6 for f in static)


@pytest.mark.parametrize("search", SEARCHES)
def test_a_prior_trusted_blindly_would_hide_the_object(
    renders: tuple[DepthPipeline, dict[str, tuple[U8, U8]], dict[str, np.ndarray]],
    monkeypatch: pytest.MonkeyPatch,
    search: str,
) -> None:
    """The control for the test above: the same frames with the change detection switched off
    (nothing ever searched again) lose the box, so finding it is the detection's doing."""
    pipe, images, truth = renders
    pipe.apply(stereo=SEARCHES[search])
    _frame(pipe, images["room"], 0, prior=True)
    monkeypatch.setattr(TemporalPrior, "spans", lambda self, left, right: [])
    monkeypatch.setattr(temporal_prior, "changed_bands", lambda left, *_: np.zeros(len(left), dtype=bool))
    entering = _frame(pipe, images["box"], 3, prior=True)
    box = truth["box"] < truth["room"] - 0.5
    near = np.nan_to_num(np.abs(entering.range[box] / truth["box"][box] - 1.0), nan=np.inf) < 0.05
    print(f"\n{search}: box within 5 % with a blind prior: {near.mean():.3f}")
    assert _searched(pipe) < 0.25
    assert near.mean() < 0.3


@pytest.mark.parametrize("search", SEARCHES)
def test_static_frames_keep_the_whole_searchs_depth(
    renders: tuple[DepthPipeline, dict[str, tuple[U8, U8]], dict[str, np.ndarray]], search: str
) -> None:
    pipe, images, truth = renders
    pipe.apply(stereo=SEARCHES[search])
    frames = [_frame(pipe, images["room"], seed, prior=True) for seed in range(4)]
    pipe.apply(stereo=SEARCHES[search])
    whole = _frame(pipe, images["room"], 3, prior=False)

    def within(frame: DepthFrame) -> float:
        return float(np.mean(np.nan_to_num(np.abs(frame.range / truth["room"] - 1.0), nan=np.inf) < 0.03))

    prior, fresh = within(frames[-1]), within(whole)
    print(f"\n{search}: room within 3 %: with the prior {prior:.3f}, whole search {fresh:.3f}")
    assert prior > fresh - 0.005
    assert np.mean(frames[-1].valid == whole.valid) > 0.98


@pytest.mark.parametrize("search", SEARCHES)
def test_the_stream_only_uses_its_history_when_asked(
    renders: tuple[DepthPipeline, dict[str, tuple[U8, U8]], dict[str, np.ndarray]], search: str
) -> None:
    pipe, images, _ = renders
    stereo = SEARCHES[search]
    pipe.apply(stereo=stereo)
    _frame(pipe, images["room"], 0, prior=True)
    _frame(pipe, images["room"], 1, prior=True)
    assert _searched(pipe) < 0.25
    # A pair outside the stream (a snapshot, a check) is searched whole and leaves the history.
    pipe.process(*images["box"])
    assert _searched(pipe) < 0.25
    _frame(pipe, images["room"], 2, prior=True)
    assert _searched(pipe) < 0.25
    # temporal_prior off in the settings: every frame searched whole.
    pipe.apply(stereo=stereo.model_copy(update={"temporal_prior": False}))
    for seed in range(2):
        _frame(pipe, images["room"], seed, prior=True)
        assert _searched(pipe) == 1.0


def _exact_stream(
    renders: tuple[DepthPipeline, dict[str, tuple[U8, U8]], dict[str, np.ndarray]],
) -> tuple[RectifiedImages, StereoMatcher]:
    """The room's rectified pair and a new exact-search matcher (an empty history)."""
    pipe, images, _ = renders
    pipe.apply(stereo=EXACT)
    return pipe.rectify(*images["room"]), pipe.in_effect.matcher


def test_the_exact_search_searches_again_at_least_every_max_age_frames(
    renders: tuple[DepthPipeline, dict[str, tuple[U8, U8]], dict[str, np.ndarray]],
) -> None:
    rect, matcher = _exact_stream(renders)
    searched = []
    for _ in range(2 * MAX_AGE + 1):
        matcher.compute(rect.left_gray, rect.right_gray, temporal_prior=True)
        searched.append(matcher.searched_fraction)
    # The same images every frame: searched on the first, then once every MAX_AGE frames.
    assert [i for i, f in enumerate(searched) if f == 1.0] == [0, MAX_AGE, 2 * MAX_AGE]


def test_a_kept_search_is_a_copy_the_caller_may_filter(
    renders: tuple[DepthPipeline, dict[str, tuple[U8, U8]], dict[str, np.ndarray]],
) -> None:
    """disparity_of filters the search's arrays in place: what the next frame keeps is untouched."""
    rect, matcher = _exact_stream(renders)
    first = matcher.compute(rect.left_gray, rect.right_gray, temporal_prior=True)
    expected = first.left.copy()
    first.left[:] = 0
    kept = matcher.compute(rect.left_gray, rect.right_gray, temporal_prior=True)
    assert matcher.searched_fraction == 0.0
    np.testing.assert_array_equal(kept.left, expected)
    assert kept.mirrored is not None and kept.left is not first.left


def test_a_corrected_calibration_searches_again(
    renders: tuple[DepthPipeline, dict[str, tuple[U8, U8]], dict[str, np.ndarray]],
) -> None:
    """The rectification refinement swaps the tables under a running stream: the history was
    found through the old ones, so the next frame is searched whole."""
    pipe, images, _ = renders
    pipe.apply(stereo=EXACT)
    _frame(pipe, images["room"], 0, prior=True)
    _frame(pipe, images["room"], 1, prior=True)
    assert _searched(pipe) == 0.0
    rig = pipe.in_effect.geometry.rig
    turned = {
        **rig.T_rig_cam,
        "right": rig.T_rig_cam["right"] @ make_transform(rot_y(np.deg2rad(0.02)), [0.0, 0.0, 0.0]),
    }
    pipe.apply(rig=Rig(rig.cameras, turned))
    _frame(pipe, images["room"], 2, prior=True)
    assert _searched(pipe) == 1.0
    _frame(pipe, images["room"], 3, prior=True)
    assert _searched(pipe) == 0.0


def _coarse_pair(seed: int, shape: tuple[int, int] = (64, 80)) -> tuple[U8, U8]:
    rng = np.random.default_rng(seed)
    return tuple(rng.integers(0, 256, shape, dtype=np.uint8) for _ in range(2))  # type: ignore[return-value]


def test_bands_change_against_the_images_they_were_searched_on() -> None:
    prior = TemporalPrior()
    left, right = _coarse_pair(0)
    assert prior.spans(left, right) == [(0, 64)], "no history: everything"
    fields = np.zeros((64, 80), dtype=np.float32)
    from rig.temporal_prior import CoarseSearch

    prior.merge(left, right, [(0, 64)], [CoarseSearch(fields, fields.copy(), 60)])
    noisy = np.clip(left.astype(int) + np.random.default_rng(1).integers(-3, 4, left.shape), 0, 255).astype(
        np.uint8
    )
    due = prior.spans(noisy, right)
    # Noise is no change: only the bands due for their periodic search (age MAX_AGE − 1 next).
    assert sum(b - a for a, b in due) <= 3 * 8
    # A small object (5×5 coarse px) in rows 30..35: its band and the neighbours.
    moved = noisy.copy()
    moved[30:35, 40:45] = 255 - moved[30:35, 40:45]
    spans = prior.spans(moved, right)
    assert any(a <= 30 and b >= 35 for a, b in spans)
    # A slow drift adds up against the searched images, not the last frame's.
    drift = [np.clip(left.astype(int) + k * 3, 0, 255).astype(np.uint8) for k in range(1, 5)]
    assert all(b - a < 64 for a, b in prior.spans(drift[0], right))
    assert prior.spans(drift[3], right) == [(0, 64)]
    assert MAX_AGE > 1


def test_a_whole_search_is_the_stream_without_history(
    renders: tuple[DepthPipeline, dict[str, tuple[U8, U8]], dict[str, np.ndarray]], tmp_path: Path
) -> None:
    pipe, images, _ = renders
    rect = pipe.rectify(*images["room"])
    a = StereoMatcher(STEREO).compute(rect.left_gray, rect.right_gray, temporal_prior=True)
    b = StereoMatcher(STEREO).compute(rect.left_gray, rect.right_gray)
    np.testing.assert_array_equal(a.left, b.left)
    assert a.mirrored is not None and b.mirrored is not None
    np.testing.assert_array_equal(a.mirrored, b.mirrored)
