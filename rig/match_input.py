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

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["NORMALISED_GAIN", "matcher_input"]

U8 = NDArray[np.uint8]
#: Grey levels per local standard deviation in the normalised image (±3σ within 8 bits).
NORMALISED_GAIN = 40.0


def matcher_input(gray: U8, blur_sigma: float, window: int, eps: float) -> U8:
    """``gray`` (H, W) uint8 as the matcher takes it (see the module doc); ``blur_sigma`` 0 and
    ``window`` 0 leave the image as it is."""
    if blur_sigma <= 0.0 and window <= 0:
        return gray
    f: NDArray[np.float32] = gray.astype(np.float32)
    if blur_sigma > 0.0:
        f = np.asarray(cv2.GaussianBlur(f, (0, 0), blur_sigma), dtype=np.float32)
    if window > 0:
        mean = cv2.blur(f, (window, window))
        var = cv2.blur(f * f, (window, window)) - mean * mean
        scale = np.float32(NORMALISED_GAIN) / (np.sqrt(np.maximum(var, 0.0)) + np.float32(eps))
        f = np.asarray((f - mean) * scale + np.float32(128.0), dtype=np.float32)
    out: U8 = np.clip(f + 0.5, 0, 255).astype(np.uint8)
    return out
