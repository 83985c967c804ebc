"""What the matcher sees: the rectified pair made alike before matching (docs/stereo.md, "Real
lenses").

Two real fisheyes seen through one rectified pair differ where a render's do not: one lens sees a
direction near its rim, blurred and darker, the other near its axis, sharp; their gains,
exposures and vignetting differ; sensor noise is amplified where the rectified view upsamples a
lens's sparse rim. SGBM's cost (Birchfield-Tomasi on a capped x-derivative) sees those
differences as mismatch, so real pairs lose matches (and gain wrong ones) where both views show
texture. :func:`matcher_input` makes the pair alike first:

1. a Gaussian blur of ``match_blur_sigma`` pixels on both views, down to the detail both keep
   (noise and a sharp lens's finest texture have no counterpart in the other view);
2. local contrast normalisation over ``match_normalise_window`` pixels,
   ``(I − μ) / (σ + ε)`` rescaled to 8 bits (mean 128, 40 levels per σ), with ε
   ``match_normalise_eps`` grey levels so that flat, noisy regions stay flat: gain, offset and
   vignetting differences between the cameras, and their slow change across the field, cancel.

Only the matcher's input changes: the subpixel refinement, the confidence and every output image
still use the rectified images as they are, so the precision of the disparity is theirs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from rig.subpixel import local_mean_variance

__all__ = ["NORMALISED_GAIN", "MatcherViews", "matcher_input", "matcher_views"]

U8 = NDArray[np.uint8]
F32 = NDArray[np.float32]
#: Grey levels per local standard deviation in the normalised image (±3σ within 8 bits).
NORMALISED_GAIN = 40.0


def matcher_input(gray: U8, blur_sigma: float, window: int, eps: float) -> U8:
    """``gray`` (H, W) uint8 as the matcher takes it (see the module doc); ``blur_sigma`` 0 and
    ``window`` 0 leave the image as it is. Rounded to the nearest level and saturated to 8 bits.
    OpenCV's arithmetic in place, without numpy's temporaries and clip: this runs on both
    views of every frame (docs/stereo.md, "The steps around the matcher")."""
    if blur_sigma <= 0.0 and window <= 0:
        return gray
    image: U8 | F32 = gray
    if blur_sigma > 0.0:
        image = _f32(cv2.GaussianBlur(gray.astype(np.float32), (0, 0), blur_sigma))
        if window <= 0:
            return _rounded_u8(image)
    mean, scale = local_mean_variance(image, window)
    cv2.sqrt(scale, dst=scale)
    scale += np.float32(eps)
    cv2.divide(NORMALISED_GAIN, scale, dst=scale)  # levels per grey level: gain / (σ + ε)
    out = _f32(cv2.subtract(image, mean, dst=mean, dtype=cv2.CV_32F))  # μ is spent: I − μ
    cv2.multiply(out, scale, dst=out)
    out += np.float32(128.0)
    return _rounded_u8(out)


def _rounded_u8(values: F32) -> U8:
    """``values`` (H, W) float32 saturated to 0…255 and rounded to nearest (consumes them)."""
    cv2.threshold(values, 255.0, 255.0, cv2.THRESH_TRUNC, dst=values)
    cv2.threshold(values, 0.0, 0.0, cv2.THRESH_TOZERO, dst=values)
    np.rint(values, out=values)
    return values.astype(np.uint8)


def _f32(x: object) -> F32:
    return np.asarray(x, dtype=np.float32)


class MatchInputSettings(Protocol):
    """The stereo parameters that make the matcher's input (rig.stereo.StereoParams)."""

    @property
    def match_blur_sigma(self) -> float: ...
    @property
    def match_normalise_window(self) -> int: ...
    @property
    def match_normalise_eps(self) -> float: ...
    @property
    def coarse_confirm(self) -> bool: ...


@dataclass(frozen=True)
class MatcherViews:
    """Both rectified views as the matcher of some parameters takes them; ``unnormalised``: the
    views with the blur only, for the coarse-to-fine search's confirmed coarse level (else None);
    ``changed``: the views are not the rectified images themselves."""

    left: U8
    right: U8
    unnormalised: tuple[U8, U8] | None
    changed: bool


def matcher_views(p: MatchInputSettings, left: U8, right: U8) -> MatcherViews:
    """The matcher's input of ``p`` from the gray rectified views: the one place it is made, for
    the pipeline and for a trial of other parameters alike."""
    a, b = (
        matcher_input(g, p.match_blur_sigma, p.match_normalise_window, p.match_normalise_eps)
        for g in (left, right)
    )
    changed = a is not left
    unnormalised = None
    if p.coarse_confirm and changed:
        # The matcher's blur, not its normalisation.
        unnormalised = (
            matcher_input(left, p.match_blur_sigma, 0, 0.0),
            matcher_input(right, p.match_blur_sigma, 0, 0.0),
        )
    return MatcherViews(a, b, unnormalised, changed)
