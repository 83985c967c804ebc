"""The evaluation's building blocks on small real renders: crop rendering, board poses, the
Reference pipeline, the image comparison and the plane metric through the real pipeline."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from calibration.models import create
from rig.evaluate.config import stereo_for
from rig.evaluate.depth_quality import REFERENCE, TRUE_LENS, build_pipelines, measure_depth, reference_rig
from rig.evaluate.distortion import run_distortion_study
from rig.evaluate.renders import (
    calibration_board_poses,
    lut_box,
    plane_distance,
    render_board,
    render_in_box,
    render_plane_shot,
)
from rig.lut import build_rectified_lut
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from rig.sim import chessboard_corners, get_preset, plane_scene, render

SMALL_VPC = RectifiedPairConfig(width=160, height=120)


def test_render_in_box_equals_the_full_render_inside_the_box() -> None:
    lens = create("kannala_brandt", 96, 72, fx=30.0, fy=30.0, cx=47.0, cy=36.0, k1=0.01, k2=-0.002,
                  k3=0.0, k4=0.0, fov_deg=190.0)  # fmt: skip
    scene = plane_scene(1.0, "paper", 3)
    full = render(scene, lens, np.eye(4), supersample=2).image
    box = (20, 10, 70, 50)
    part = render_in_box(scene, lens, np.eye(4), box, supersample=2, background=7)
    # The crop's rays equal the full image's to the last bits; a ray landing on a texel's
    # 1/32 sub-step boundary of cv2.remap may round the other way (seen: 2 of 2000 pixels).
    diff = np.abs(part[10:50, 20:70].astype(int) - full[10:50, 20:70].astype(int))
    assert np.count_nonzero(diff) <= 10 and diff.max() <= 8
    outside = np.ones_like(part, dtype=bool)
    outside[10:50, 20:70] = False
    assert (part[outside] == 7).all()


@pytest.mark.parametrize("preset", ["paper-sim", "prototype"])
def test_board_poses_cover_the_image_circle_up_to_the_lens_limit(preset: str) -> None:
    lens = get_preset(preset).scaled(0.5).rig.cameras["left"]
    poses = calibration_board_poses(lens, 12, np.random.default_rng(0))
    X = chessboard_corners(9, 6, 0.05)
    top, azimuths = [], []
    for T in poses:
        p = X @ T[:3, :3].T + T[:3, 3]
        _, ok = lens.project(p)
        assert ok.all()  # every corner is imaged
        top.append(float(np.degrees(np.arccos(p[:, 2] / np.linalg.norm(p, axis=1))).max()))
        c = p.mean(axis=0)
        azimuths.append(math.degrees(math.atan2(c[1], c[0])))
    limit = math.degrees(lens.max_theta)
    assert max(top) <= limit
    assert max(top) >= limit - 6.0  # the rim boards reach the field's edge
    if limit > 90.0:
        assert sum(t > 90.0 for t in top) >= 3  # corners past 90° off axis (190° lens)
    rim = [a for a, t in zip(azimuths, top, strict=True) if t > limit - 12.0]
    assert np.ptp(np.sin(np.radians(rim))) > 1.5 and np.ptp(np.cos(np.radians(rim))) > 1.5  # all around


def test_rendered_rim_board_is_found_by_the_detector_where_the_lens_puts_it() -> None:
    from calibration.targets import detect_chessboard

    lens = get_preset("prototype").scaled(0.5).rig.cameras["right"]
    T = calibration_board_poses(lens, 12, np.random.default_rng(0))[-1]
    corners = detect_chessboard(render_board(lens, T, (9, 6), 0.05, 2), (9, 6))
    assert corners is not None
    exact, _ = lens.project(chessboard_corners(9, 6, 0.05) @ T[:3, :3].T + T[:3, 3])
    assert np.sqrt(np.mean(np.sum((corners - exact) ** 2, axis=1))) < 0.3


def test_reference_rig_gives_the_same_vpc_pair_with_identity_tables() -> None:
    rig = get_preset("prototype").scaled(0.5).rig
    pair = design_rectified_pair(rig, SMALL_VPC)
    ref = reference_rig(pair)
    again = design_rectified_pair(ref, SMALL_VPC)
    assert again.baseline_m == pytest.approx(pair.baseline_m, rel=1e-12)
    assert again.camera.to_dict() == pair.camera.to_dict()
    for name in ("left", "right"):
        np.testing.assert_allclose(again.R_cam_rect[name], np.eye(3), atol=1e-12)
        lut = build_rectified_lut(ref.cameras[name], again.R_cam_rect[name], again.camera)
        img = np.random.default_rng(1).integers(0, 256, (120, 160), dtype=np.uint8)
        np.testing.assert_array_equal(lut.remap(img), img)  # an exact identity: no resampling


def test_plane_shot_truth_and_the_reference_pipeline_measure_the_plane(tmp_path: Path) -> None:
    preset = get_preset("paper-sim").scaled(0.25)
    rig = preset.rig
    pair = design_rectified_pair(rig, SMALL_VPC)
    stereo = stereo_for(SMALL_VPC, 3.0)
    pipes, errors = build_pipelines(
        {REFERENCE: reference_rig(pair), TRUE_LENS: rig}, SMALL_VPC, stereo, tmp_path
    )
    assert errors == {}
    boxes = {n: lut_box(pipes[TRUE_LENS].luts[n], rig.cameras[n]) for n in ("left", "right")}
    shot = render_plane_shot(rig, pair, 4.0, "noise", boxes, phase_px=0.3, seed=0, supersample=2,
                             noise_std=0.0, vignetting=0.0)  # fmt: skip
    # The plane sits where its disparity is fx/k + phase: the truth says so at every pixel.
    z = plane_distance(pair, 4.0, 0.3)
    assert pair.fx * pair.baseline_m / z == pytest.approx(pair.fx / 4.0 + 0.3)
    np.testing.assert_allclose(shot.depth_true, z, rtol=1e-5)
    samples = {
        s.curve: s.stats for s in measure_depth(pipes, shot, pair, seed=0, vicinity_frac=0.1, samples=1000)
    }
    ref, fish = samples[REFERENCE], samples[TRUE_LENS]
    # Most of the matchable VPC sees the plane with depth; errors are a small fraction of Z
    # (a 0.3 px disparity error would be 0.3 / 40 = 0.75 %).
    for s in (ref, fish):
        assert s.n_points > 5000 and s.valid_frac > 0.6
        assert s.rms_m < 0.0075 * z
    assert ref.rms_m < fish.rms_m  # resampling the fisheye image costs accuracy


def test_image_difference_ranks_a_wrong_focal_length_below_the_true_lens() -> None:
    rig = get_preset("paper-sim").scaled(0.25).rig
    pair = design_rectified_pair(rig, SMALL_VPC)
    lens = rig.cameras["left"]
    p = lens.param_dict
    poor = lens.replace(fx=p["fx"] * 1.01, fy=p["fy"] * 1.01)  # 1 % focal length error
    study = run_distortion_study(
        rig, pair, {TRUE_LENS: lens, "poor": poor}, seed=0, supersample=2, step=lambda _: None
    )
    true, bad = study.results[TRUE_LENS], study.results["poor"]
    assert true.error is None and bad.error is None
    assert true.valid_frac == 1.0
    assert bad.mad_whole > true.mad_whole + 1.0
    assert study.reference.shape == (120, 160)
    assert true.diff_image is not None and true.diff_image.shape == (120, 160)
