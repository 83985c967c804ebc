"""The honest renderer's lens model (rig.sim.lens_effects) against its formulas and OpenCV: the
field-dependent blur (a blend of Gaussians with the right variance), rim darkening, exposure,
response curve and sensor noise; the ideal lens changes nothing."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from calibration.geometry import make_transform
from rig.errors import ConfigError
from rig.evaluate.renders import render_in_box
from rig.sim import ImageTexture, Scene, TexturedRect, get_preset, render, room_scene
from rig.sim.lens_effects import (
    HONEST_LENS,
    IDEAL_LENS,
    SIGMA_STEP_PX,
    CameraExposure,
    LensEffects,
    apply_lens,
    blur_by_field,
)


def _texture(shape: tuple[int, int], seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.resize(
        rng.uniform(0, 255, (shape[0] // 4, shape[1] // 4)), shape[::-1], interpolation=cv2.INTER_NEAREST
    )
    return img.astype(np.float32)[:, :, None]


def test_constant_blur_is_opencvs_gaussian() -> None:
    img = _texture((120, 160))
    for sigma in (0.8, 1.3):
        out = blur_by_field(img, np.full((120, 160), sigma))
        radius = math.ceil(4 * sigma)
        ref = cv2.GaussianBlur(img[:, :, 0], (2 * radius + 1,) * 2, sigma, borderType=cv2.BORDER_REFLECT)
        np.testing.assert_allclose(out[:, :, 0], ref, atol=1e-3)


def test_a_varying_blur_gives_each_point_the_variance_of_its_sigma() -> None:
    """Isolated points blurred where σ varies across the image (steps between the pre-blurred
    levels included): each spot's second moment is σ² of its pixel."""
    h, w = 200, 400
    img = np.zeros((h, w, 1), np.float32)
    points = [(100, c) for c in range(20, 400, 40)]
    for r, c in points:
        img[r, c] = 1000.0
    sigma = np.broadcast_to(np.linspace(1.0, 3.2, w), (h, w)).copy()
    out = blur_by_field(img, sigma)[:, :, 0]
    for r, c in points:
        win = out[r - 16 : r + 17, c - 16 : c + 17].astype(np.float64)
        yy, xx = np.mgrid[-16:17, -16:17]
        var = float((win * (xx**2 + yy**2)).sum() / win.sum() / 2.0)
        # A blend of the two neighbouring levels is off a true Gaussian's σ by nothing in variance;
        # OpenCV's sampled kernel adds ~1 %.
        assert math.sqrt(var) == pytest.approx(sigma[r, c], rel=0.015), (c, math.sqrt(var), sigma[r, c])
    assert (
        np.diff(np.unique(np.round(sigma, 6))) > 0
    ).all() and sigma.max() - sigma.min() > 4 * SIGMA_STEP_PX


def test_rim_darkening_exposure_and_response_follow_their_formulas() -> None:
    lens = LensEffects(
        name="test",
        illumination=(-0.2, -0.1),
        response_pivot=100.0,
        exposures=(CameraExposure(1.0), CameraExposure(0.8, 1.25)),
    )
    h, w = 50, 60
    cos_theta = np.cos(np.broadcast_to(np.linspace(0.0, 1.5, w), (h, w)))
    shade = np.full((h, w, 1), 120.0, np.float32)
    rng = np.random.default_rng(0)
    x = np.arccos(cos_theta) / 1.5
    ri = 1.0 - 0.2 * x**2 - 0.1 * x**4
    left = apply_lens(shade, cos_theta, 1.5, lens, 0, rng)[:, :, 0]
    np.testing.assert_allclose(left, 120.0 * ri, rtol=1e-5)
    right = apply_lens(shade, cos_theta, 1.5, lens, 1, rng)[:, :, 0]
    np.testing.assert_allclose(right, 0.8 * 100.0 * (120.0 * ri / 100.0) ** 1.25, rtol=1e-5)
    assert lens.exposure(3) == lens.exposure(1)  # cameras past the list repeat it


def test_noise_has_the_read_and_shot_variance() -> None:
    lens = LensEffects(name="test", read_noise=1.5, shot_noise=0.05)
    rng = np.random.default_rng(1)
    for level in (20.0, 200.0):
        shade = np.full((400, 400, 1), level, np.float32)
        out = apply_lens(shade, np.ones((400, 400)), 1.6, lens, 0, rng)
        expected = 1.5**2 + 0.05 * level
        assert float(out.var()) == pytest.approx(expected, rel=0.02)
        assert float(out.mean()) == pytest.approx(level, abs=0.02)


def test_the_ideal_lens_renders_what_no_lens_does_and_the_honest_one_differs() -> None:
    cam = get_preset("prototype").scaled(0.125).rig.cameras["left"]
    scene = room_scene(0)
    plain = render(scene, cam, np.eye(4), supersample=2, seed=3)
    ideal = render(scene, cam, np.eye(4), supersample=2, seed=3, lens=IDEAL_LENS)
    np.testing.assert_array_equal(plain.image, ideal.image)
    honest = render(scene, cam, np.eye(4), supersample=2, seed=3, lens=HONEST_LENS.scaled(0.125))
    np.testing.assert_array_equal(honest.distance, plain.distance)  # the truth is the lens's business
    diff = np.abs(honest.image.astype(int) - plain.image)[plain.valid]
    assert diff.mean() > 1.0


def test_a_uniform_wall_darkens_to_the_rim_as_the_lens_says() -> None:
    """A grey wall filling a 190° lens: the rendered brightness against the angle off the axis
    follows the relative illumination (no blur, no noise, away from the circle's edge)."""
    cam = get_preset("prototype").scaled(0.25).rig.cameras["left"]
    lens = LensEffects(name="test", illumination=(-0.1, -0.25))
    grey = ImageTexture(np.full((2, 2), 200.0, np.float32), (1.0, 1.0))
    wall = Scene([TexturedRect(make_transform(np.eye(3), [0, 0, 0.01]), (1e4, 1e4), grey)])
    wall.rects.append(
        TexturedRect(make_transform(np.diag([1.0, -1.0, -1.0]), [0, 0, -0.01]), (1e4, 1e4), grey)
    )
    out = render(wall, cam, np.eye(4), supersample=1, lens=lens)
    v, u = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
    rays, _ = cam.unproject(np.stack([u.ravel(), v.ravel()], 1))
    x = (np.arccos(np.clip(rays[:, 2], -1, 1)) / cam.max_theta).reshape(out.image.shape)
    inner = out.valid & (x < 0.98)
    expected = np.rint(200.0 * (1 - 0.1 * x**2 - 0.25 * x**4))
    np.testing.assert_array_equal(out.image[inner], expected[inner])


def test_bad_lens_effects_are_refused() -> None:
    for kwargs in ({"blur_centre_px": -1.0}, {"read_noise": math.nan}, {"blur_power": 0.0}):
        with pytest.raises(ConfigError):
            LensEffects(name="bad", **kwargs)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="exposure"):
        LensEffects(name="bad", exposures=(CameraExposure(gain=0.0),))


def test_a_crop_through_the_lens_is_the_full_render_there() -> None:
    """rig.evaluate's crops render larger by the blur's reach: inside the box the crop through
    the honest optics (noise off) equals the full render."""
    preset = get_preset("prototype").scaled(0.25)
    cam = preset.rig.cameras["right"]
    lens = preset.lens.noiseless()
    scene = room_scene(0)
    box = (40, 30, 150, 120)
    full = render(scene, cam, np.eye(4), supersample=2, lens=lens, camera_index=1).image
    crop = render_in_box(scene, cam, np.eye(4), box, supersample=2, lens=lens, camera_index=1)
    x0, y0, x1, y1 = box
    np.testing.assert_array_equal(crop[y0:y1, x0:x1], full[y0:y1, x0:x1])
    assert lens.reach_px(1) > 0 and (crop[:y0] == 0).all()
