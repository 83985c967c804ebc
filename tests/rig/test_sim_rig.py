"""Simulated rigs: the divergent mount, the presets, and the paper's Fig. 6 check that a fisheye
render remapped through the VPC lookup reproduces the Reference pinhole render."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from calibration.geometry import rot_y
from calibration.models import CameraModel, create
from rig.errors import ConfigError
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from rig.sim import PRESETS, divergent_rig, get_preset, plane_scene, render, room_scene, scale_camera


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))


def _lens() -> CameraModel:
    return create("equidistant", 100, 100, fx=30.0, fy=30.0, cx=49.5, cy=49.5, fov_deg=180.0)


def test_divergent_rig_ideal_mount() -> None:
    rig = divergent_rig(_lens(), _lens(), 0.2, 90.0)
    assert rig.names == ["left", "right"]
    np.testing.assert_allclose(rig.center("left"), [-0.1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(rig.center("right"), [0.1, 0, 0], atol=1e-15)
    assert rig.baseline() == pytest.approx(0.2)
    assert _angle_deg(rig.axis("left"), rig.axis("right")) == pytest.approx(90.0)
    s = math.sqrt(0.5)
    np.testing.assert_allclose(rig.axis("left"), [-s, 0, s], atol=1e-15)  # looks left-forward
    np.testing.assert_allclose(rig.axis("right"), [s, 0, s], atol=1e-15)
    bisector = rig.axis("left") + rig.axis("right")
    np.testing.assert_allclose(bisector / np.linalg.norm(bisector), [0, 0, 1], atol=1e-15)
    # Both cameras keep y down: their x axes lie in the horizontal plane.
    for name in rig.names:
        assert abs(rig.T_rig_cam[name][1, 0]) < 1e-15 and rig.T_rig_cam[name][1, 1] == pytest.approx(1.0)


def test_divergent_rig_non_ideal_mount() -> None:
    rig = divergent_rig(_lens(), _lens(), 0.072, 87.0, pitch_deg=2.0, roll_deg=1.5)
    assert rig.baseline() == pytest.approx(0.072)
    # Yaw difference 87°, then the right axis tilts 2° up (towards -y).
    a_r = rig.axis("right")
    assert math.degrees(math.asin(-a_r[1])) == pytest.approx(2.0)
    yaw_r = math.degrees(math.atan2(a_r[0], a_r[2]))
    yaw_l = math.degrees(math.atan2(rig.axis("left")[0], rig.axis("left")[2]))
    assert yaw_r - yaw_l == pytest.approx(87.0)
    # Roll turns the right camera about its own axis: its x axis leaves the horizontal plane.
    ideal = divergent_rig(_lens(), _lens(), 0.072, 87.0, pitch_deg=2.0)
    x_roll, x_ideal = rig.T_rig_cam["right"][:3, 0], ideal.T_rig_cam["right"][:3, 0]
    assert _angle_deg(x_roll, x_ideal) == pytest.approx(1.5)
    np.testing.assert_allclose(rig.axis("right"), ideal.axis("right"), atol=1e-15)
    # The left camera is untouched by pitch/roll.
    np.testing.assert_allclose(
        rig.T_rig_cam["left"], divergent_rig(_lens(), _lens(), 0.072, 87.0).T_rig_cam["left"]
    )
    # The VPC design (docs/design.md) still rectifies it: the VPC x axis is the baseline.
    pair = design_rectified_pair(rig)
    assert pair.baseline_m == pytest.approx(0.072)


@pytest.mark.parametrize(
    "kwargs",
    [{"baseline_m": 0.0}, {"baseline_m": float("nan")}, {"angle_deg": 180.0}, {"pitch_deg": 120.0}],
)
def test_divergent_rig_rejects_bad_mounts(kwargs: dict[str, float]) -> None:
    args = {"baseline_m": 0.1, **kwargs}
    with pytest.raises(ConfigError):
        divergent_rig(_lens(), _lens(), **args)


def test_presets_match_the_paper() -> None:
    assert set(PRESETS) == {"paper-sim", "prototype"}
    sim = get_preset("paper-sim")
    assert sim.rig.baseline() == pytest.approx(0.20)
    assert _angle_deg(sim.rig.axis("left"), sim.rig.axis("right")) == pytest.approx(90.0)
    for cam in sim.rig.cameras.values():
        assert cam.name == "equidistant" and cam.fov_deg == 180.0
    assert sim.rig.cameras["left"] == sim.rig.cameras["right"]
    cam = sim.rig.cameras["left"]
    # 90° off axis lands on the image edge: the circle is inscribed.
    px, ok = cam.project(np.array([[1.0, 0.0, 1e-12]]))
    assert ok[0] and px[0, 0] == pytest.approx(cam.width - 0.5, abs=1e-6)

    proto = get_preset("prototype")
    assert proto.rig.baseline() == pytest.approx(0.072)
    assert _angle_deg(proto.rig.axis("left"), proto.rig.axis("right")) == pytest.approx(90.0)
    table2 = {"left": (3.78e-4, 4.48e-5, 5.79e-3, -2.41e-3), "right": (3.80e-4, 1.89e-3, -1.20e-3, -1.22e-4)}
    for name, cam in proto.rig.cameras.items():
        p = cam.param_dict
        assert (
            cam.name == "kannala_brandt" and (cam.width, cam.height) == (1280, 960) and cam.fov_deg == 190.0
        )
        assert (p["k1"], p["k2"], p["k3"], p["k4"]) == table2[name]
        assert 260 <= p["fx"] <= 300
        # 95° off axis at ~480-510 px from the principal point (paper Fig. 9).
        px, ok = cam.project(
            np.array([[math.sin(math.radians(95)), 0.0, math.cos(math.radians(95))]]), in_image=False
        )
        r95 = px[0, 0] - p["cx"]
        assert 480 <= r95 <= 510
        # Cut off vertically, whole horizontally, off-centre.
        assert p["cy"] - r95 < -0.5 or p["cy"] + r95 > cam.height - 0.5
        assert p["cx"] - r95 > -0.5 and p["cx"] + r95 < cam.width - 0.5
        assert abs(p["cx"] - 639.5) > 5 or abs(p["cy"] - 479.5) > 5


def test_get_preset_copies_and_rejects_unknown_names() -> None:
    a = get_preset("prototype")
    a.rig.T_rig_cam["left"][0, 3] = 99.0
    assert get_preset("prototype").rig.T_rig_cam["left"][0, 3] == pytest.approx(-0.036)
    with pytest.raises(ConfigError, match="paper-sim, prototype"):
        get_preset("unity")


def test_scale_camera_keeps_pixel_geometry() -> None:
    cam = get_preset("prototype").rig.cameras["right"]
    small = scale_camera(cam, 0.25)
    assert (small.width, small.height) == (320, 240)
    pts = np.random.default_rng(0).normal(size=(200, 3)) + np.array([0.0, 0.0, 1.5])
    big_px, ok_big = cam.project(pts)
    small_px, ok_small = small.project(pts)
    both = ok_big & ok_small
    assert both.sum() > 100
    # Pixel centres: u_small = (u + 0.5) * s - 0.5.
    np.testing.assert_allclose(small_px[both], (big_px[both] + 0.5) * 0.25 - 0.5, atol=1e-9)
    with pytest.raises(ConfigError):
        scale_camera(cam, 0.0)


def _remap_to_rect(
    fisheye: np.ndarray, cam: CameraModel, vpc: CameraModel, R_cam_rect: np.ndarray
) -> np.ndarray:
    """The paper's eq. (10), written out here: p_fisheye = π_f(R · π_pinhole⁻¹(p_rect))."""
    u, v = np.meshgrid(np.arange(vpc.width, dtype=float), np.arange(vpc.height, dtype=float))
    rays, _ = vpc.unproject(np.stack([u.ravel(), v.ravel()], axis=1))
    px, ok = cam.project(rays @ R_cam_rect.T)
    mx = np.where(ok, px[:, 0], -10).reshape(vpc.height, vpc.width).astype(np.float32)
    my = np.where(ok, px[:, 1], -10).reshape(vpc.height, vpc.width).astype(np.float32)
    return cv2.remap(fisheye, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


@pytest.mark.parametrize(("preset", "texture"), [("paper-sim", "noise"), ("prototype", "blobs")])
def test_fisheye_remapped_to_vpc_reproduces_the_reference(preset: str, texture: str) -> None:
    """Fig. 6: fisheye render → LUT remap vs the Reference pinhole at the VPC pose."""
    p = get_preset(preset).scaled(0.5)
    pair = design_rectified_pair(p.rig, RectifiedPairConfig(width=320, height=240))
    # A texture both cameras resolve, so differences measure geometry, not lost resolution.
    scene = plane_scene(5 * p.rig.baseline(), texture, seed=1, texture_px=256)
    inner = (slice(24, 216), slice(32, 288))
    for name in ("left", "right"):
        cam = p.rig.cameras[name]
        fisheye = render(scene, cam, p.rig.T_rig_cam[name]).image
        reference = render(scene, pair.camera, pair.T_rig_rect[name]).image.astype(np.float64)
        remapped = _remap_to_rect(fisheye, cam, pair.camera, pair.R_cam_rect[name]).astype(np.float64)
        mad = np.abs(remapped - reference)[inner].mean()
        shift, _ = cv2.phaseCorrelate(remapped[inner], reference[inner])
        assert mad < 3.0, (name, mad)
        assert np.hypot(*shift) < 0.1, (name, shift)
        # The check has teeth: a 0.3° error in R moves the image ~1 px and the difference triples.
        wrong = _remap_to_rect(fisheye, cam, pair.camera, rot_y(math.radians(0.3)) @ pair.R_cam_rect[name])
        assert np.abs(wrong.astype(np.float64) - reference)[inner].mean() > 2 * mad + 3


@pytest.mark.slow
def test_prototype_full_size_render() -> None:
    """One render at the prototype's real size (1280x960, supersample 3, 11 M rays)."""
    p = get_preset("prototype")
    cam = p.rig.cameras["right"]
    out = render(
        room_scene(0), cam, p.rig.T_rig_cam["right"], noise_std=p.noise_std, vignetting=p.vignetting, seed=0
    )
    assert out.image.shape == (960, 1280) and out.depth.shape == (960, 1280)
    prm = cam.param_dict
    u, v = np.meshgrid(np.arange(1280.0), np.arange(960.0))
    th = math.radians(95.0)
    k1, k2, k3, k4 = prm["k1"], prm["k2"], prm["k3"], prm["k4"]
    rd95 = th * (1 + k1 * th**2 + k2 * th**4 + k3 * th**6 + k4 * th**8)
    rd = np.hypot((u - prm["cx"]) / prm["fx"], (v - prm["cy"]) / prm["fy"])
    edge = np.abs(rd - rd95) < 1e-9
    np.testing.assert_array_equal(out.valid[~edge], (rd <= rd95)[~edge])
    assert np.isfinite(out.depth[out.valid]).all() and (out.depth[out.valid] != 0).all()
    assert (out.image[~out.valid] == 0).all()
    # The room is at most ~12 m away; the lens sees behind itself (depth < 0 past 90°).
    assert np.nanmax(out.distance) < 12.5 and np.nanmin(out.depth) < 0
