"""DepthPipeline: the issue's accuracy criterion, the DepthFrame contract, point clouds,
VPCs that leave the lens, thread-safe parameter swaps, input errors."""

from __future__ import annotations

import logging
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

import rig.postprocess as finish_module
from calibration.geometry import make_transform, rot_y
from calibration.models import create
from calibration.rig import Rig
from rig.errors import ConfigError, LutError, PipelineError
from rig.filters import TemporalFilter, median_filter
from rig.match_input import matcher_input
from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams, create_opencv_matcher
from rig.subpixel import refine_disparity
from tests.helpers.shots import PINHOLE, StereoShot, central_box, plane_shot, prototype_rig

VPC = RectifiedPairConfig(width=320, height=240)
SMALL_STEREO = StereoParams(disparity_range=64)


@pytest.mark.slow
@pytest.mark.parametrize("coarse_to_fine", [True, False], ids=["coarse-to-fine", "exact"])
def test_done_when_prototype_plane_depth_within_2_percent(lut_cache: Path, coarse_to_fine: bool) -> None:
    """Prototype renders (full 1280×960 KB 190° lenses, the preset's 1.5 grey levels
    of noise and vignetting) of a textured plane at 3.7, 7.6 and 14.2 baselines; the pinhole VPC
    (640×480, 90°) and default stereo parameters (and the exact search); ≥ 95 % of the central
    50 % × 50 % box has depth within 2 % of the truth."""
    stereo = StereoParams(coarse_to_fine=coarse_to_fine)
    pipe = DepthPipeline(prototype_rig(1.0), PINHOLE, stereo, cache_dir=lut_cache)
    print(
        f"\nprototype plane, pinhole VPC, coarse_to_fine {coarse_to_fine}: "
        "central box within 2% of true depth"
    )
    # Measured (docs/stereo.md's figures): depth RMS (mm) and disparity RMS (px) at each distance.
    measured = {
        True: {3.7: (0.061, 0.020), 7.6: (0.26, 0.020), 14.2: (1.31, 0.029)},
        False: {3.7: (0.095, 0.031), 7.6: (0.26, 0.020), 14.2: (1.45, 0.032)},
    }[coarse_to_fine]
    for k in (3.7, 7.6, 14.2):
        shot = plane_shot(k, scale=1.0, noise_std=1.5, vignetting=0.35)
        frame = pipe.process(shot.left, shot.right)
        box = central_box(frame.depth.shape)
        truth = shot.depth[box]
        assert np.isfinite(truth).all()
        rel = np.abs(frame.depth[box] - truth) / truth
        within = float(np.mean(np.nan_to_num(rel, nan=np.inf) <= 0.02))
        rmse = float(np.sqrt(np.nanmean((frame.depth[box] - truth) ** 2)))
        d_rms = float(np.sqrt(np.nanmean((frame.disparity[box] - shot.disparity[box]) ** 2)))
        print(
            f"  {k:5.1f} B (Z = {truth.mean():.3f} m, d = {shot.disparity[box].mean():.2f} px): "
            f"{100 * within:.2f}% within 2%, depth RMS {1000 * rmse:.3f} mm, disparity RMS {d_rms:.3f} px"
        )
        assert within >= 0.999  # docs/stereo.md's 100 %; 95 % was asked for
        assert (1000 * rmse, d_rms) == pytest.approx(measured[k], rel=0.3)


@pytest.fixture(scope="module")
def shot() -> StereoShot:
    return plane_shot(5.0, scale=0.5, vpc=VPC)


@pytest.fixture()
def pipe(shot: StereoShot, lut_cache: Path) -> DepthPipeline:
    return DepthPipeline(shot.rig, VPC, SMALL_STEREO, cache_dir=lut_cache)


def test_depth_frame_contract(pipe: DepthPipeline, shot: StereoShot) -> None:
    frame = pipe.process(shot.left, shot.right, seq=7, ts_ns=123)
    assert (frame.seq, frame.ts_ns) == (7, 123)
    for arr, dtype in ((frame.depth, np.float32), (frame.disparity, np.float32), (frame.valid, np.bool_)):
        assert arr.shape == (240, 320) and arr.dtype == dtype
    assert frame.confidence is not None and frame.confidence.dtype == np.float32
    assert frame.left_rect.shape == (240, 320) and frame.left_rect.dtype == np.uint8
    assert set(frame.timings_ms) == {"remap", "match", "refine", "filters", "depth", "total"}
    assert all(v >= 0 for v in frame.timings_ms.values())
    assert frame.timings_ms["total"] >= frame.timings_ms["match"]
    assert np.isnan(frame.depth[~frame.valid]).all() and np.isnan(frame.disparity[~frame.valid]).all()
    assert np.isfinite(frame.depth[frame.valid]).all() and (frame.disparity[frame.valid] > 0).all()
    v = frame.valid
    assert np.allclose(frame.depth[v], pipe.pair.fx * pipe.baseline_m / frame.disparity[v], rtol=1e-6)
    assert pipe.valid_fraction == {"left": 1.0, "right": 1.0}
    box = central_box(frame.depth.shape)
    assert np.nanmedian(np.abs(frame.depth[box] - shot.depth[box]) / shot.depth[box]) < 0.005


@pytest.mark.parametrize("stereo", [{}, {"subpixel": False}, {"median": 0}, {"temporal_alpha": 0.5}])
def test_finish_on_the_active_columns_is_exactly_the_whole_frame(
    shot: StereoShot, lut_cache: Path, monkeypatch: pytest.MonkeyPatch, stereo: dict[str, float]
) -> None:
    """The finish stage works on the columns around the valid pixels only (the matcher leaves
    its first disparity_range columns invalid): bit for bit what the whole frame gives."""
    pipe = DepthPipeline(shot.rig, VPC, StereoParams(disparity_range=64, **stereo), cache_dir=lut_cache)  # type: ignore[arg-type]
    matched = pipe.match(pipe.rectify(shot.left, shot.right))
    cols = finish_module.active_columns(pipe._disparity(matched).valid, 9)
    assert cols.start >= 64 - 9, "nothing to leave out"
    window = [pipe.postprocess(matched, i) for i in range(2)]
    monkeypatch.setattr(finish_module, "active_columns", lambda valid, margin: slice(0, valid.shape[1]))
    pipe = DepthPipeline(shot.rig, VPC, StereoParams(disparity_range=64, **stereo), cache_dir=lut_cache)  # type: ignore[arg-type]
    whole = [pipe.postprocess(matched, i) for i in range(2)]  # twice: the temporal filter's history
    for a, b in zip(window, whole, strict=True):
        assert np.array_equal(a.valid, b.valid) and a.valid.mean() > 0.5
        for name in ("disparity", "depth", "confidence"):
            x, y = getattr(a, name), getattr(b, name)
            assert (x is None) == (y is None)
            if x is not None:
                assert np.array_equal(x, y, equal_nan=True), name


def _finish_by_the_stage_functions(
    left: NDArray[np.uint8], right: NDArray[np.uint8], p: StereoParams, temporal: TemporalFilter, fx_b: float
) -> dict[str, NDArray[np.generic] | None]:
    """The stages written out in one pass over the whole frame, from the references their parts
    are tested against: the matcher's input (tests/rig/test_match_input.py), the bare OpenCV
    matcher, the single-pass refinement (on the images as they are), the median, confidence
    exp(−σ/σ0) where valid, the temporal filter and depth fx·B/d."""
    seen = (
        matcher_input(g, p.match_blur_sigma, p.match_normalise_window, p.match_normalise_eps)
        for g in (left, right)
    )
    fixed = create_opencv_matcher(p).compute(*seen)
    valid = fixed >= p.min_disparity * 16
    disparity = np.where(valid, fixed / np.float32(16.0), np.float32(np.nan)).astype(np.float32)
    sigma = None
    if p.subpixel or p.confidence:
        ref = refine_disparity(
            left, right, disparity, valid, p.subpixel_window, apply=p.subpixel, want_sigma=p.confidence
        )
        disparity, sigma = ref.disparity, ref.sigma
    if p.median:
        disparity, valid = median_filter(disparity, valid, p.median)
    disparity = temporal(disparity, valid)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.float32(fx_b) / disparity
    depth[disparity <= 0] = np.nan
    valid &= np.isfinite(depth)
    confidence = None
    if sigma is not None:
        confidence = np.where(valid, np.exp(-sigma / np.float32(p.confidence_sigma)), np.float32(0.0))
    return {"disparity": np.where(valid, disparity, np.float32(np.nan)), "valid": valid, "depth": depth,
            "confidence": confidence}  # fmt: skip


@pytest.mark.parametrize(
    "stereo",
    [{}, {"subpixel": False}, {"confidence": False, "median": 0}, {"median": 3, "temporal_alpha": 0.5}],
)
def test_finish_is_the_stage_functions_in_one_pass(
    shot: StereoShot, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, stereo: dict[str, object]
) -> None:
    """The finish stage (its sections, on the active columns, in one band) gives bit for bit
    what its parts give in one pass over the whole frame. (More bands differ only in the box
    filters' summation order: bench/test_fast_paths.py.)"""
    monkeypatch.setattr(finish_module, "refine_pool", lambda: None)
    # The exact search, so that the bare OpenCV matcher is its reference.
    params = StereoParams.model_validate({"disparity_range": 64, "coarse_to_fine": False, **stereo})
    pipe = DepthPipeline(shot.rig, VPC, params, cache_dir=tmp_path)
    assert pipe.valid_fraction == {"left": 1.0, "right": 1.0}, "no LUT masks to apply"
    rect = pipe.rectify(shot.left, shot.right)
    temporal = TemporalFilter(params.temporal_alpha, params.temporal_reset)
    for seq, left in enumerate((rect.left_gray, np.roll(rect.left_gray, 1, axis=1))):
        # Two frames, the second one a pixel nearer: the temporal filter's history and reset.
        moved = replace(rect, left_gray=left)
        got = pipe.postprocess(pipe.match(moved), seq)
        want = _finish_by_the_stage_functions(
            left, rect.right_gray, params, temporal, pipe.pair.fx * pipe.baseline_m
        )
        assert got.valid.mean() > 0.5
        for name, expected in want.items():
            value = getattr(got, name)
            assert (value is None) == (expected is None), name
            if expected is not None:
                assert value.dtype == expected.dtype and np.array_equal(value, expected, equal_nan=True), name


def test_colour_frames_give_colour_vpc_images_and_rgb_point_colours(
    pipe: DepthPipeline, shot: StereoShot
) -> None:
    tint = np.array([0.6, 0.8, 1.0], dtype=np.float32)  # B, G, R
    left = (shot.left[..., None] * tint).astype(np.uint8)
    right = (shot.right[..., None] * tint).astype(np.uint8)
    frame = pipe.process(left, right)
    assert frame.left_rect.shape == (240, 320, 3) and frame.right_rect.shape == (240, 320, 3)
    gray = pipe.process(shot.left, shot.right)
    both = frame.valid & gray.valid
    assert both.mean() > 0.6
    assert np.nanmedian(np.abs(frame.disparity[both] - gray.disparity[both])) < 0.05
    pts, colours = pipe.point_cloud(frame)
    assert colours.shape == pts.shape and colours.dtype == np.uint8
    # Blue is the darkest channel of the tint: in RGB order it comes last.
    assert colours[:, 2].mean() < colours[:, 1].mean() < colours[:, 0].mean()


def test_point_cloud_lies_on_the_plane_in_the_rig_frame(pipe: DepthPipeline, shot: StereoShot) -> None:
    frame = pipe.process(shot.left, shot.right)
    pts, colours = pipe.point_cloud(frame)
    assert pts.dtype == np.float32 and pts.shape[1] == 3 and pts.shape[0] == frame.valid.sum()
    plane_z = 5.0 * shot.rig.baseline()  # the plane is z = const in the rig (= world) frame
    assert np.median(np.abs(pts[:, 2] - plane_z)) < 0.005 * plane_z
    assert np.percentile(np.abs(pts[:, 2] - plane_z), 95) < 0.02 * plane_z
    # Left VPC centre ray points along the rig's z: the cloud is centred near x = -B/2.
    assert abs(np.median(pts[:, 1])) < 0.2 * plane_z
    gray_colours = colours[:, 0]
    assert np.array_equal(gray_colours, colours[:, 1])
    sub, _ = pipe.point_cloud(frame, stride=4)
    assert 0 < sub.shape[0] <= pts.shape[0] // 10


def test_footprint_traces_the_vpc_border_in_each_fisheye(pipe: DepthPipeline) -> None:
    for name in ("left", "right"):
        poly = pipe.footprint(name, samples=16)
        assert poly.shape == (64, 2)
        lut = pipe.luts[name]
        corners = {(0, 0): 0, (0, 319): 16, (239, 319): 32, (239, 0): 48}
        for (r, c), i in corners.items():
            assert np.allclose(poly[i], [lut.map_x[r, c], lut.map_y[r, c]], atol=2e-3)
        model = pipe.rig.cameras[name]
        assert model.in_image(poly).all()
    with pytest.raises(ConfigError, match="no camera"):
        pipe.footprint("middle")


def test_lut_comes_from_the_cache_the_second_time(shot: StereoShot, tmp_path: Path) -> None:
    first = DepthPipeline(shot.rig, VPC, SMALL_STEREO, cache_dir=tmp_path)
    again = DepthPipeline(shot.rig, VPC, SMALL_STEREO, cache_dir=tmp_path)
    assert not any(i.hit for i in first.lut_info.values())
    assert all(i.hit for i in again.lut_info.values())
    assert np.array_equal(first.luts["left"].map1, again.luts["left"].map1)


@pytest.mark.parametrize(
    "config",
    [RectifiedPairConfig(hfov_deg=150.0), RectifiedPairConfig(projection="pinhole", yaw_deg=60.0)],
    ids=["hfov150", "yaw60"],
)
def test_vpc_leaving_the_lens_reports_its_valid_fraction(
    config: RectifiedPairConfig, lut_cache: Path, caplog: pytest.LogCaptureFixture
) -> None:
    rig = prototype_rig(1.0)
    with caplog.at_level(logging.WARNING, logger="rig.pipeline"):
        pipe = DepthPipeline(rig, config, cache_dir=lut_cache)
    low = {n: f for n, f in pipe.valid_fraction.items() if f < 1.0}
    assert low, "this VPC leaves a lens's field"
    assert all(0.0 < f < 1.0 for f in low.values())
    for name, f in low.items():
        assert any(name in r.getMessage() and f"{100 * f:.1f}%" in r.getMessage() for r in caplog.records)
    # Not a crop: the VPC keeps its size; invalid pixels are black and never get depth.
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (960, 1280), dtype=np.uint8)
    right = np.roll(left, -5, axis=1)
    frame = pipe.process(left, right)
    assert frame.depth.shape == (480, 640)
    lmask = pipe.luts["left"].valid
    assert (frame.left_rect[~lmask] == 0).all()
    assert not (frame.valid & ~lmask).any()


def test_vpc_that_sees_nothing_is_an_error(tmp_path: Path) -> None:
    lens = create("equidistant", 400, 400, fx=150.0, fy=150.0, cx=199.5, cy=199.5, fov_deg=120.0)
    rig = Rig(
        {"left": lens, "right": lens.replace()},
        {
            "left": make_transform(rot_y(-0.3), [-0.05, 0, 0]),
            "right": make_transform(rot_y(0.3), [0.05, 0, 0]),
        },
    )
    with pytest.raises(LutError, match="sees nothing"):
        DepthPipeline(
            rig, RectifiedPairConfig(pitch_deg=80.0, hfov_deg=20.0, width=64, height=48), cache_dir=tmp_path
        )


def test_bad_inputs_are_clear_errors(pipe: DepthPipeline, shot: StereoShot) -> None:
    with pytest.raises(PipelineError, match="left image is 10x10 but its calibration is 640x480"):
        pipe.process(np.zeros((10, 10), np.uint8), shot.right)
    with pytest.raises(PipelineError, match="right image must be a uint8"):
        pipe.process(shot.left, np.asarray(shot.right, dtype=np.float32))
    with pytest.raises(PipelineError, match="gray"):
        pipe.process(np.dstack([shot.left] * 4), shot.right)
    with pytest.raises(ConfigError, match="below the rectified view's width"):
        pipe.apply(stereo=StereoParams(disparity_range=320))
    with pytest.raises(ConfigError, match="below the rectified view's width"):
        DepthPipeline(shot.rig, VPC, StereoParams(disparity_range=320), cache_dir=pipe.cache.directory)


def test_update_stereo_is_thread_safe_and_takes_effect_next_frame(
    pipe: DepthPipeline, shot: StereoShot
) -> None:
    errors: list[BaseException] = []
    seen: list[bool] = []
    stop = threading.Event()

    def worker() -> None:
        try:
            while not stop.is_set():
                f = pipe.process(shot.left, shot.right)
                seen.append(f.confidence is None)
                assert f.valid.mean() > 0.5
        except BaseException as err:  # surfaced below
            errors.append(err)

    t = threading.Thread(target=worker)
    t.start()
    try:
        for i in range(20):
            pipe.apply(
                stereo=StereoParams(disparity_range=64, confidence=bool(i % 2), median=(0, 3, 5)[i % 3])
            )
            threading.Event().wait(0.01)
    finally:
        stop.set()
        t.join(timeout=60)
    assert not errors, errors
    assert len(seen) >= 2
    pipe.apply(stereo=StereoParams(disparity_range=64, confidence=False))
    assert pipe.stereo.confidence is False
    assert pipe.process(shot.left, shot.right).confidence is None
