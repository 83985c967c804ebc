"""Procedural textures: seeded, distinct, seamless, detailed at every scale; exact sampling."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rig.errors import ConfigError
from rig.sim import TEXTURES, CheckerTexture, ImageTexture, make_texture
from rig.sim.patterns import PATTERNS
from rig.sim.textures import texture_name


@pytest.mark.parametrize("kind", TEXTURES)
def test_pattern_is_deterministic_given_seed(kind: str) -> None:
    # Call the generator itself twice (make_texture caches): same seed -> same pixels.
    a = PATTERNS[kind](np.random.default_rng(5), 256)
    b = PATTERNS[kind](np.random.default_rng(5), 256)
    c = PATTERNS[kind](np.random.default_rng(6), 256)
    assert a.dtype == np.float32 and a.shape == (256, 256)
    np.testing.assert_array_equal(a, b)
    # Another seed gives another texture (checker-noise keeps its checker, so not uncorrelated).
    assert np.abs(a - c).mean() > 15.0


def test_kinds_are_distinct_and_in_range() -> None:
    images = {k: make_texture(k, 0, size_px=512).image for k in TEXTURES}
    assert len(TEXTURES) >= 5
    for k, img in images.items():
        assert img.min() >= 0 and img.max() <= 255, k
        assert img.std() > 35, f"{k}: too little contrast"
    for i, a in enumerate(TEXTURES):
        for b in TEXTURES[i + 1 :]:
            r = np.corrcoef(images[a].ravel(), images[b].ravel())[0, 1]
            assert abs(r) < 0.5, (a, b, r)


@pytest.mark.parametrize("kind", TEXTURES)
def test_tiles_join_without_a_seam(kind: str) -> None:
    img = make_texture(kind, 3, size_px=512).image.astype(np.float64)
    interior_x = np.abs(np.diff(img, axis=1)).mean(axis=0)  # per column pair
    interior_y = np.abs(np.diff(img, axis=0)).mean(axis=1)
    seam_x = np.abs(img[:, -1] - img[:, 0]).mean()
    seam_y = np.abs(img[-1] - img[0]).mean()
    # A seam would look like two unrelated pixels (~62 grey levels apart for std 55).
    assert seam_x <= 1.25 * interior_x.max()
    assert seam_y <= 1.25 * interior_y.max()


@pytest.mark.parametrize("kind", TEXTURES)
def test_detail_at_every_scale(kind: str) -> None:
    """Band-pass contrast survives downsampling by 1..32: something to match whether a texel
    covers a thirtieth of a pixel or several pixels (2 to 20 baselines and beyond)."""
    img = make_texture(kind, 1, size_px=1024).image
    for f in (1, 2, 4, 8, 16, 32):
        small = cv2.resize(img, (1024 // f, 1024 // f), interpolation=cv2.INTER_AREA)
        band = small - cv2.GaussianBlur(small, (0, 0), 1.0)
        assert band.std() > 5.0, (kind, f, float(band.std()))


def test_texture_names_and_indices() -> None:
    assert texture_name(0) == TEXTURES[0]
    assert texture_name("2") == TEXTURES[2]
    assert texture_name("paper") == "paper"
    for bad in ("marble", 99, -1, True):
        with pytest.raises(ConfigError, match="known: noise"):
            texture_name(bad)


def _bilinear_wrap(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    h, w = img.shape
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    g = img.astype(np.float64)

    def at(yy: np.ndarray, xx: np.ndarray) -> np.ndarray:
        return g[yy % h, xx % w]

    top = at(y0, x0) * (1 - fx) + at(y0, x0 + 1) * fx
    bottom = at(y0 + 1, x0) * (1 - fx) + at(y0 + 1, x0 + 1) * fx
    return top * (1 - fy) + bottom * fy


def test_image_texture_samples_bilinearly_in_metres() -> None:
    rng = np.random.default_rng(0)
    img = rng.uniform(0, 255, (40, 60)).astype(np.float32)
    tex = ImageTexture(img, (3.0, 2.0), repeat=True, offset_m=(0.25, -0.5))
    st = rng.uniform(-5, 5, (2000, 2))
    # Texel centres sit at (i + 0.5) * size / n: coordinate -> texel index minus a half.
    x = (st[:, 0] - 0.25) * 60 / 3.0 - 0.5
    y = (st[:, 1] + 0.5) * 40 / 2.0 - 0.5
    expected = _bilinear_wrap(img, x, y)
    # cv2.remap interpolates with 1/32-texel weights: at most 1/32 of a neighbour difference.
    np.testing.assert_allclose(tex.sample(st), expected, atol=255 / 32)
    assert np.abs(tex.sample(st) - expected).mean() < 1.0
    # Exactly at texel centres the value is the texel.
    i, j = rng.integers(0, 60, 50), rng.integers(0, 40, 50)
    centres = np.stack([(i + 0.5) * 3.0 / 60 + 0.25, (j + 0.5) * 2.0 / 40 - 0.5], axis=1)
    np.testing.assert_allclose(tex.sample(centres), img[j, i], atol=1e-3)


def test_checker_texture_is_exact() -> None:
    tex = CheckerTexture(cols=4, rows=3, square_m=0.1, margin_m=0.05)
    st = np.array([[0.01, 0.01], [0.06, 0.06], [0.16, 0.06], [0.06, 0.16], [0.16, 0.16], [0.46, 0.2]])
    # margin, square (0,0) white, (1,0) black, (0,1) black, (1,1) white, right margin
    np.testing.assert_array_equal(tex.sample(st), [255, 255, 0, 0, 255, 255])


def test_tinted_texture_keeps_grey_order() -> None:
    grey = make_texture("noise", 0, size_px=64)
    tinted = grey.tinted((20, 30, 40), (200, 220, 250))
    assert tinted.channels == 3 and tinted.image.shape == (64, 64, 3)
    st = np.random.default_rng(1).uniform(0, 1, (500, 2))
    luma = tinted.sample_as(st, 1)
    g = grey.sample(st)
    assert np.corrcoef(luma, g)[0, 1] > 0.999
    bgr = grey.sample_as(st, 3)
    np.testing.assert_array_equal(bgr[:, 0], g)


def test_bad_texture_arguments() -> None:
    with pytest.raises(ConfigError):
        make_texture("noise", size_px=4)
    with pytest.raises(ConfigError):
        ImageTexture(np.zeros((4, 4, 2), np.float32), (1.0, 1.0))
    with pytest.raises(ConfigError):
        ImageTexture(np.zeros((4, 4), np.float32), (0.0, 1.0))
