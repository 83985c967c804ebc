"""Every texture stays matchable for stereo at the VPC resolution (640x480, 90° HFOV) from 2 to
20 baselines, through the whole fisheye path: render both fisheyes, remap them to the VPC pair
(eq. (10), written out here), run OpenCV's SGBM and compare with the true disparity fx·B/Z."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rig.rectified import RectifiedPair, RectifiedPairConfig, design_rectified_pair
from rig.sim import TEXTURES, Preset, get_preset, plane_scene, render


@pytest.fixture(scope="module")
def paper_rig_maps() -> tuple[Preset, RectifiedPair, dict[str, tuple[np.ndarray, np.ndarray]]]:
    preset = get_preset("paper-sim")
    pair = design_rectified_pair(preset.rig, RectifiedPairConfig(projection="pinhole"))
    vpc = pair.camera
    u, v = np.meshgrid(np.arange(vpc.width, dtype=float), np.arange(vpc.height, dtype=float))
    rays, _ = vpc.unproject(np.stack([u.ravel(), v.ravel()], axis=1))
    maps = {}
    for name in ("left", "right"):
        px, ok = preset.rig.cameras[name].project(rays @ pair.R_cam_rect[name].T)
        mx = np.where(ok, px[:, 0], -10).reshape(vpc.height, vpc.width).astype(np.float32)
        my = np.where(ok, px[:, 1], -10).reshape(vpc.height, vpc.width).astype(np.float32)
        maps[name] = (mx, my)
    return preset, pair, maps


@pytest.mark.slow
@pytest.mark.parametrize("texture", TEXTURES)
@pytest.mark.parametrize("k", [2.3, 19.7])
def test_texture_is_matchable_through_the_fisheye_path(
    paper_rig_maps: tuple[Preset, RectifiedPair, dict[str, tuple[np.ndarray, np.ndarray]]],
    texture: str,
    k: float,
) -> None:
    preset, pair, maps = paper_rig_maps
    baseline = preset.rig.baseline()
    scene = plane_scene(k * baseline, texture, seed=2)
    rect_images = {}
    for name in ("left", "right"):
        fisheye = render(scene, preset.rig.cameras[name], preset.rig.T_rig_cam[name], supersample=2).image
        rect_images[name] = cv2.remap(fisheye, *maps[name], cv2.INTER_LINEAR)
    true = pair.camera.fx * baseline / (k * baseline)
    ndisp = 16 * int(np.ceil((true + 24) / 16))
    sgbm = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=ndisp, blockSize=5, P1=8 * 25, P2=32 * 25, uniquenessRatio=10,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )  # fmt: skip
    disp = sgbm.compute(rect_images["left"], rect_images["right"]).astype(np.float32) / 16.0
    region = disp[40:-40, ndisp + 40 : -40]
    good = np.abs(region - true) < 1.0
    assert good.mean() > 0.95, f"{texture} at {k} baselines: {good.mean():.3f} within 1 px of {true:.2f}"
    assert np.median(np.abs(region - true)) < 0.25
