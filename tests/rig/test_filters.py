"""Post-filters: behaviour on constructed inputs, and each one measured on the virtual
environment (valid fraction and error with and without it; ``pytest -s`` prints the table)."""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from rig.filters import (
    TemporalFilter,
    copy_where,
    fill_where,
    left_right_consistent,
    median_filter,
    visible_in_right,
)
from rig.pipeline import DepthFrame, DepthPipeline
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams
from tests.helpers.shots import StereoShot, add_noise, central_box, plane_shot, room_shot

F32 = NDArray[np.float32]
VPC = RectifiedPairConfig(width=320, height=240)
BASE: dict[str, Any] = {"disparity_range": 64}


# ----- constructed inputs -------------------------------------------------------------------------
def test_lr_consistency_on_constructed_disparities() -> None:
    h, w = 4, 40
    left = np.full((h, w), 5.0, dtype=np.float32)
    valid = np.ones((h, w), dtype=bool)
    right = np.full((h, w), 5.0, dtype=np.float32)
    right[:, 20:25] = 9.0  # disagrees: left columns 25..29 land there
    right[:, 30] = np.nan  # no right disparity: left column 35 lands there
    ok = left_right_consistent(left, valid, right, 1.0)
    assert not ok[:, 25:30].any() and not ok[:, 35].any()
    assert not ok[:, :5].any(), "matches left of the right image fail"
    assert ok[:, 5:25].all() and ok[:, 30:35].all() and ok[:, 36:].all()
    # Columns the right-view matcher never searched are no evidence either way.
    assert left_right_consistent(left, valid, right, 1.0, right_blind_from=30)[:, 35].all()
    assert left_right_consistent(left, valid, right, 4.5)[:, 25:30].all()


def test_lr_consistency_agrees_with_a_numpy_lookup() -> None:
    # Disparities in 1/16 px put many matches exactly half-way between two columns: OpenCV's
    # nearest-neighbour lookup must round those like np.rint and clip at the borders.
    rng = np.random.default_rng(7)
    h, w = 50, 120
    left = (rng.integers(-16, 60 * 16, (h, w)) / 16.0).astype(np.float32)
    valid = rng.random((h, w)) > 0.2
    right = (rng.integers(0, 60 * 16, (h, w)) / 16.0).astype(np.float32)
    right[rng.random((h, w)) < 0.1] = np.nan
    x = np.arange(w, dtype=np.float32)[None, :]
    cols = np.rint(x - np.where(valid, left, 0.0))
    at = np.take_along_axis(right, np.clip(cols, 0, w - 1).astype(np.intp), axis=1)
    with np.errstate(invalid="ignore"):
        agree = (np.abs(left - at) <= 2.0) | (cols >= 90)
    expected = valid & agree & (x - np.where(valid, left, 0.0) >= -0.5)
    got = left_right_consistent(left, valid, right, 2.0, right_blind_from=90)
    assert 0.01 < expected.mean() < 0.99
    np.testing.assert_array_equal(got, expected)
    seen = rng.random((h, w)) > 0.3
    np.testing.assert_array_equal(
        visible_in_right(left, valid, seen),
        valid & np.take_along_axis(seen, np.clip(cols, 0, w - 1).astype(np.intp), axis=1),
    )


def test_visible_in_right_uses_the_right_lut_mask() -> None:
    disp = np.full((3, 30), 10.0, dtype=np.float32)
    right_ok = np.ones((3, 30), dtype=bool)
    right_ok[:, 5:8] = False
    out = visible_in_right(disp, np.ones((3, 30), dtype=bool), right_ok)
    assert not out[:, 15:18].any() and out[:, 18:].all() and out[:, 10:15].all()


def test_median_removes_spikes_and_never_fills_holes() -> None:
    rng = np.random.default_rng(0)
    disp = (20 + rng.normal(0, 0.05, (40, 40))).astype(np.float32)
    disp[10, 10] = 35.0  # a spike
    valid = np.ones((40, 40), dtype=bool)
    valid[25:35, 25:35] = False
    disp[~valid] = np.nan
    out, ok = median_filter(disp, valid, 5)
    assert abs(out[10, 10] - 20) < 0.2
    assert not ok[26:34, 26:34].any(), "holes stay holes"
    assert not (ok & ~valid).any(), "the median never invents values"
    assert np.isnan(out[~ok]).all()
    assert np.nanstd(out[:20, :20]) < np.nanstd(disp[:20, :20][np.isfinite(disp[:20, :20])]) / 1.5
    with pytest.raises(ValueError, match="3 or 5"):
        median_filter(disp, valid, 7)


def test_median_drops_valid_pixels_whose_window_is_mostly_invalid() -> None:
    disp = np.full((20, 20), np.nan, dtype=np.float32)
    disp[:, 10:] = 7.5  # a valid half
    disp[4, 3] = disp[4, 4] = 9.0  # two valid pixels among invalid ones
    valid = np.isfinite(disp)
    for ksize in (3, 5):
        out, ok = median_filter(disp, valid, ksize)
        assert not ok[4, 3] and not ok[4, 4] and np.isnan(out[4, 3])
        assert ok[:, 11:].all() and (out[:, 11:] == 7.5).all()
        assert np.array_equal(np.isnan(out), ~ok)


def test_fill_and_copy_where_write_in_place_through_views() -> None:
    a = np.zeros((6, 8), dtype=np.float32)
    mask = np.zeros((6, 8), dtype=bool)
    mask[::2, ::3] = True
    fill_where(a[1:5, 2:7], np.nan, mask[1:5, 2:7])  # a window: strided rows
    want = np.zeros((6, 8), dtype=np.float32)
    want[1:5, 2:7][mask[1:5, 2:7]] = np.nan
    assert np.array_equal(a, want, equal_nan=True)
    fill_where(a, np.inf, mask)
    fill_where(a[:2, :3], 0.5, np.ones((2, 3), dtype=bool))  # a smaller view of the cached image
    assert a[0, 0] == 0.5 and np.isinf(a[0, 3]) and a[4, 3] == np.inf
    src = np.arange(48, dtype=np.float32).reshape(6, 8)
    copy_where(a, src, ~mask)
    assert np.array_equal(a[~mask], src[~mask]) and np.isinf(a[2, 0])
    with pytest.raises(ValueError, match="cannot write"):
        copy_where(np.zeros((6, 8)), src, mask)  # float64: OpenCV would make a new array


def test_temporal_filter_averages_static_pixels_and_restarts_on_change() -> None:
    rng = np.random.default_rng(1)
    f = TemporalFilter(0.8, reset=1.0)
    valid = np.ones((30, 30), dtype=bool)
    outs = [f((10 + rng.normal(0, 0.2, (30, 30))).astype(np.float32), valid) for _ in range(15)]
    assert np.std(outs[-1] - 10) < 0.5 * 0.2
    # A jump (motion) restarts those pixels at once instead of dragging the old value.
    jumped = np.full((30, 30), 10.0, dtype=np.float32)
    jumped[:, :10] = 14.0
    out = f(jumped, valid)
    assert np.allclose(out[:, :10], 14.0)
    # New invalid pixels are invalid at once: no stale depth.
    holes = valid.copy()
    holes[5, 5] = False
    assert np.isnan(f(jumped, holes)[5, 5])
    with pytest.raises(ValueError, match="alpha"):
        TemporalFilter(1.0)


# ----- measured on renders ------------------------------------------------------------------------
def _errors(frame: DepthFrame, shot: StereoShot) -> dict[str, float]:
    """Over pixels with ground truth: valid fraction, RMS of the errors under 3 px (a few gross
    mismatches would swamp a plain RMS), median error and the > 1 px / > 3 px fractions."""
    truth = shot.disparity
    has = np.isfinite(truth)
    ok = frame.valid & has
    err = np.abs(frame.disparity - truth)[ok]
    return {
        "valid": float(ok.sum() / has.sum()),
        "rms3": float(np.sqrt(np.mean(err[err < 3] ** 2))),
        "median": float(np.median(err)),
        "bad1": float(np.mean(err > 1)),
        "bad3": float(np.mean(err > 3)),
    }


def _rate(frame: DepthFrame, shot: StereoShot, mask: NDArray[np.bool_], threshold: float) -> float:
    """Fraction of ``mask``'s pixels (with ground truth) whose error in ``frame`` exceeds ``threshold``."""
    sel = mask & np.isfinite(shot.disparity)
    assert sel.sum() > 20
    return float(np.mean(np.abs(frame.disparity - shot.disparity)[sel] > threshold))


@pytest.fixture(scope="module")
def room() -> StereoShot:
    return room_shot(0, scale=0.5, vpc=VPC)


@pytest.fixture(scope="module")
def pipe(lut_cache: Path) -> DepthPipeline:
    return DepthPipeline(room_shot(0, scale=0.5, vpc=VPC).rig, VPC, cache_dir=lut_cache)


def _measure(pipe: DepthPipeline, shot: StereoShot, noise_seed: int = 1, **params: Any) -> DepthFrame:
    pipe.apply(stereo=StereoParams(**(BASE | params)))
    return pipe.process(add_noise(shot.left, 1.5, noise_seed), add_noise(shot.right, 1.5, noise_seed + 1))


#: Measured (docs/stereo.md, post-filter table), per search (coarse-to-fine, exact with the
#: left-right check at full resolution, exact with it at half resolution: the default): valid
#: fraction, RMS of errors < 3 px, median error, fractions of errors > 1 px and > 3 px.
ROOM_FIGURES = {
    "coarse-to-fine": {
        "all filters off": (0.797, 0.489, 0.219, 0.0484, 0.00178),
        "defaults": (0.793, 0.251, 0.089, 0.0103, 0.00021),
        "no LR check": (0.800, 0.258, 0.090, 0.0131, 0.00090),
    },
    "exact": {
        "all filters off": (0.782, 0.346, 0.194, 0.0190, 0.00363),
        "defaults": (0.771, 0.207, 0.085, 0.0066, 0.00042),
        "no LR check": (0.780, 0.223, 0.086, 0.0079, 0.00042),
    },
    "half check": {
        "all filters off": (0.782, 0.346, 0.194, 0.0190, 0.00363),
        "defaults": (0.777, 0.207, 0.085, 0.0064, 0.00042),
        "no LR check": (0.780, 0.223, 0.086, 0.0079, 0.00042),
    },
}
SEARCHES = {
    "coarse-to-fine": {"coarse_to_fine": True},
    "exact": {"coarse_to_fine": False, "lr_check_scale": 1},
    "half check": {"coarse_to_fine": False, "lr_check_scale": 2},
}


@pytest.mark.parametrize("search_name", list(SEARCHES))
def test_each_filter_measured_in_the_room(pipe: DepthPipeline, room: StereoShot, search_name: str) -> None:
    """Room scene (walls, floor, boxes: slants, depth edges, occlusions, a repetitive text
    wall), 1.5 grey levels of noise. Each filter is judged by what it removes or changes."""
    rows: dict[str, dict[str, Any]] = {
        "all filters off": dict(
            speckle_size=0, median=0, subpixel=False, lr_check=False, match_normalise_window=0
        ),
        "defaults": {},
        "no matcher normalisation": dict(match_normalise_window=0),
        "no speckle removal": dict(speckle_size=0),
        "no median": dict(median=0),
        "median 3": dict(median=3),
        "no LR check": dict(lr_check=False),
        "no subpixel": dict(subpixel=False),
    }
    search = SEARCHES[search_name]
    frames = {name: _measure(pipe, room, **search, **kw) for name, kw in rows.items()}
    stats = {name: _errors(f, room) for name, f in frames.items()}
    print(
        f"\nRoom, VPC 320x240, {search_name}: valid fraction; RMS of errors < 3 px; "
        "median; > 1 px and > 3 px fractions"
    )
    for name, st in stats.items():
        print(
            f"{name:20s} valid {st['valid']:.3f}  RMS<3 {st['rms3']:.3f} px  median {st['median']:.3f} px  "
            f">1px {100 * st['bad1']:.2f}%  >3px {100 * st['bad3']:.3f}%"
        )
    for name, want in ROOM_FIGURES[search_name].items():
        st = stats[name]
        got = (st["valid"], st["rms3"], st["median"], st["bad1"], st["bad3"])
        assert got == pytest.approx(want, rel=0.15, abs=3e-4), name
    d, df = stats["defaults"], frames["defaults"]
    # Speckle removal: the pixels it removes are mostly gross errors; it costs < 1 % of pixels.
    nosp = frames["no speckle removal"]
    removed = nosp.valid & ~df.valid
    print(f"speckle removal drops {removed.sum()} px")
    assert d["valid"] > stats["no speckle removal"]["valid"] - 0.01
    if search_name != "exact":
        # The coarse level removed the coarse speckles before the fine level saw them (the
        # half-resolution check: the check removes them, its coarse search finding none there):
        # little is left for it, and nothing it removes is worse than what stays.
        assert removed.sum() < 0.001 * removed.size
        assert (
            d["bad3"] <= stats["no speckle removal"]["bad3"] * 1.01
        )  # (shares of slightly different counts)
    else:
        assert _rate(nosp, room, removed, 3) > 20 * _rate(df, room, df.valid, 3)
        assert stats["no speckle removal"]["bad3"] > d["bad3"]
    # LR check: the pixels it removes are mostly wrong; fewer > 1 px errors remain.
    nolr = frames["no LR check"]
    removed = nolr.valid & ~df.valid
    print(f"LR check drops {removed.sum()} px, {100 * _rate(nolr, room, removed, 1):.0f}% of them > 1 px off")
    assert not (df.valid & ~nolr.valid).any()
    assert _rate(nolr, room, removed, 1) > 10 * _rate(df, room, df.valid, 1)
    assert d["bad1"] < stats["no LR check"]["bad1"]
    # Median: fewer > 1 px errors and smaller errors, for under 1 % of the valid pixels.
    assert d["bad1"] < stats["no median"]["bad1"] and d["rms3"] < stats["no median"]["rms3"]
    assert d["valid"] > stats["no median"]["valid"] - 0.01
    # Subpixel refinement: smaller errors.
    assert (
        d["rms3"] < 0.85 * stats["no subpixel"]["rms3"] and d["median"] < 0.7 * stats["no subpixel"]["median"]
    )


def test_confidence_ranks_errors_in_the_room(pipe: DepthPipeline, room: StereoShot) -> None:
    frame = _measure(pipe, room)
    assert frame.confidence is not None
    assert frame.confidence.dtype == np.float32
    assert (frame.confidence >= 0).all() and (frame.confidence <= 1).all()
    assert (frame.confidence[~frame.valid] == 0).all()
    ok = frame.valid & np.isfinite(room.disparity)
    err = np.abs(frame.disparity - room.disparity)[ok]
    conf = frame.confidence[ok]
    edges = np.quantile(conf, [0.0, 0.25, 0.5, 0.75, 1.0])
    med, rms3, bad1 = [], [], []
    for lo, hi in itertools.pairwise(edges):
        e = err[(conf >= lo) & (conf <= hi)]
        med.append(float(np.median(e)))
        rms3.append(float(np.sqrt(np.mean(e[e < 3] ** 2))))
        bad1.append(float(np.mean(e > 1)))
    print(
        "\nconfidence quartiles (low -> high): median error "
        + " ".join(f"{m:.3f}" for m in med)
        + " px; RMS<3 "
        + " ".join(f"{r:.3f}" for r in rms3)
        + " px; >1 px "
        + " ".join(f"{100 * b:.2f}%" for b in bad1)
    )
    # Higher confidence, lower error: in the typical error, the spread and the gross errors.
    assert all(a > b for a, b in itertools.pairwise(med))
    assert all(a > b for a, b in itertools.pairwise(rms3))
    assert bad1[0] > 5 * bad1[-1] and med[0] > 1.5 * med[-1]
    assert (med[0], med[-1]) == pytest.approx((0.154, 0.058), rel=0.15)  # measured, in docs/stereo.md


def test_temporal_filter_measured_on_noisy_frames(lut_cache: Path) -> None:
    """A static plane under heavy sensor noise (6 grey levels), 8 frames."""
    shot = plane_shot(7.6, scale=0.5, vpc=VPC)
    pipe = DepthPipeline(shot.rig, VPC, cache_dir=lut_cache)
    box = central_box(shot.depth.shape)
    last = {}
    for alpha in (0.0, 0.8):
        pipe.apply(stereo=StereoParams(**BASE, temporal_alpha=alpha))
        for i in range(8):
            frame = pipe.process(add_noise(shot.left, 6.0, 10 + i), add_noise(shot.right, 6.0, 50 + i))
        err = (frame.disparity - shot.disparity)[box]
        last[alpha] = (float(np.isfinite(err).mean()), float(np.sqrt(np.nanmean(err**2))))
    print(
        f"\nplane, noise 6 grey levels, frame 8: alpha 0 RMS {last[0.0][1]:.3f} px, "
        f"alpha 0.8 RMS {last[0.8][1]:.3f} px (valid {last[0.0][0]:.3f} / {last[0.8][0]:.3f})"
    )
    assert last[0.8][1] < 0.85 * last[0.0][1]
    assert (last[0.0][1], last[0.8][1]) == pytest.approx((0.036, 0.024), rel=0.15)  # measured
    assert last[0.8][0] >= last[0.0][0] - 0.01
