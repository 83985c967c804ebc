"""The matcher's input (rig.match_input): gain, offset and slow shading between the two views
cancel, flat regions are not turned into texture, and it is the identity when off; on the real
ring it is what lets the matcher keep its matches (docs/ring.md gives the figures)."""

from __future__ import annotations

import numpy as np

from rig.match_input import NORMALISED_GAIN, matcher_input


def _texture(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(128 + 30 * rng.standard_normal((120, 160)), 0, 255)


def test_gain_offset_and_shading_cancel() -> None:
    base = _texture()
    left = np.clip(base, 0, 255).astype(np.uint8)
    # The other camera: 0.7 the gain, 20 levels darker, vignetted by a slow ramp across the view.
    ramp = np.linspace(1.0, 0.8, base.shape[1])[None, :]
    right = np.clip(0.7 * base * ramp + 20, 0, 255).astype(np.uint8)
    a, b = (matcher_input(img, 0.0, 31, 16.0).astype(np.float64) for img in (left, right))
    inner = (slice(16, -16), slice(16, -16))
    raw_gap = np.abs(left.astype(float) - right.astype(float))[inner].mean()
    gap = np.abs(a - b)[inner].mean()
    assert raw_gap > 20 and gap < 0.25 * raw_gap
    assert np.corrcoef(a[inner].ravel(), b[inner].ravel())[0, 1] > 0.98


def test_flat_regions_stay_flat_and_texture_is_scaled() -> None:
    rng = np.random.default_rng(1)
    flat = np.clip(100 + 1.5 * rng.standard_normal((80, 80)), 0, 255).astype(np.uint8)  # noise only
    out = matcher_input(flat, 0.0, 31, 16.0).astype(np.float64)
    # Noise of σ 1.5 stays within a few levels: ε keeps it from becoming texture.
    assert out[16:-16, 16:-16].std() < 1.5 * NORMALISED_GAIN / 16.0 + 0.5
    textured = matcher_input(_texture().astype(np.uint8), 0.0, 31, 16.0).astype(np.float64)
    assert textured[16:-16, 16:-16].std() > 25.0
    assert abs(textured[16:-16, 16:-16].mean() - 128.0) < 3.0


def test_off_is_the_image_itself() -> None:
    img = _texture().astype(np.uint8)
    assert matcher_input(img, 0.0, 0, 16.0) is img
    blurred = matcher_input(img, 1.5, 0, 16.0)
    assert blurred.shape == img.shape and blurred.dtype == np.uint8 and blurred.std() < img.std()
