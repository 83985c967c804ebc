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


def _reference(gray: np.ndarray, window: int, eps: float) -> np.ndarray:
    """The module doc's formula in float64 numpy: means over ``window``² by summed-area tables,
    mirrored at the border without repeating it (OpenCV's default), rounded to nearest."""
    r = window // 2
    padded = np.pad(gray.astype(np.float64), r, mode="reflect")

    def box_mean(x: np.ndarray) -> np.ndarray:
        s = np.pad(x.cumsum(0).cumsum(1), ((1, 0), (1, 0)))
        total = s[window:, window:] - s[:-window, window:] - s[window:, :-window] + s[:-window, :-window]
        return total / window**2

    mean, mean_sq = box_mean(padded), box_mean(padded**2)
    sigma = np.sqrt(np.maximum(mean_sq - mean**2, 0.0))
    out = (gray - mean) * NORMALISED_GAIN / (sigma + eps) + 128.0
    return np.clip(np.rint(out), 0, 255)


def test_against_the_formula() -> None:
    rng = np.random.default_rng(2)
    img = np.clip(128 + 60 * rng.standard_normal((97, 131)), 0, 255).astype(np.uint8)
    img[:, :40] //= 4  # dark and flat-ish: ε matters there
    for window, eps in ((31, 16.0), (15, 4.0)):
        ours = matcher_input(img, 0.0, window, eps).astype(np.int64)
        ref = _reference(img, window, eps)
        # float32 against float64: a value near a half level may round the other way.
        assert np.abs(ours - ref).max() <= 1
        assert (ours == ref).mean() > 0.9995  # measured: every pixel equal
