"""What a real fisheye and its sensor do to the ideal image: the honest renderer's lens model.

Applied to the renderer's box-filtered image (grey levels, linear in the scene's radiance), per
pixel of field angle θ off the optical axis (x = θ / θmax, θmax the lens's field limit):

1. **Sharpness falling with field angle and defocus**: a Gaussian PSF of
   ``σ(x) = hypot(σ0 + σ1·x^p, defocus)`` pixels. Done as a blend of a few images blurred at
   fixed σ (steps of at most :data:`SIGMA_STEP_PX`), each pixel mixing the two levels either
   side of its σ with the weights that give the mix exactly the variance σ² (a mix of two
   Gaussians this close is Gaussian-shaped to well under a grey level).
2. **Rim darkening** (relative illumination): ``× (1 + c1·x² + c2·x⁴ + …)``.
3. **Exposure**: ``× gain`` (per camera: exposure time and analogue gain).
4. **Sensor noise**: gaussian with variance ``read² + shot·v`` grey levels² at signal v (the
   shot noise's Poisson variance, ``shot`` = grey levels per electron), seeded.
5. **Response**: ``255 · (v / 255)^(1/γ)`` (per camera), then rounding to 8 bits.

The curves are functions of the relative field x, so one fit serves lenses of any field and
resolution; σ is in the lens's own pixels. :data:`HONEST_LENS` holds the parameters fitted to
real fisheye images (``python -m bench.lens_fit``; docs/evaluation.md, "The honest renderer");
:data:`IDEAL_LENS` turns everything off.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from rig.errors import ConfigError

__all__ = [
    "HONEST_LENS",
    "IDEAL_LENS",
    "LENS_CHOICES",
    "SIGMA_STEP_PX",
    "CameraExposure",
    "LensEffects",
    "apply_lens",
    "blur_by_field",
]

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

#: The largest σ step between two pre-blurred levels (pixels).
SIGMA_STEP_PX = 0.25
#: ``rig sim --lens`` choices.
LENS_CHOICES = ("honest", "ideal")


@dataclass(frozen=True)
class CameraExposure:
    """One camera's own settings: ``gain`` (exposure × analogue gain, relative), ``gamma`` of
    its response curve and ``defocus_px``, a constant Gaussian σ added in quadrature."""

    gain: float = 1.0
    gamma: float = 1.0
    defocus_px: float = 0.0


@dataclass(frozen=True)
class LensEffects:
    """The lens and sensor effects of a rig's cameras (module docstring); ``exposures`` per
    camera in the rig's order, repeated cyclically for more cameras (empty: all nominal)."""

    name: str = "ideal"
    blur_centre_px: float = 0.0
    blur_rim_px: float = 0.0
    blur_power: float = 2.0
    illumination: tuple[float, ...] = ()
    read_noise: float = 0.0
    shot_noise: float = 0.0
    exposures: tuple[CameraExposure, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        values = {
            "blur_centre_px": self.blur_centre_px,
            "blur_rim_px": self.blur_rim_px,
            "read_noise": self.read_noise,
            "shot_noise": self.shot_noise,
        }
        for key, value in values.items():
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"lens effects {self.name!r}: {key} must be >= 0, got {value!r}")
        if not (math.isfinite(self.blur_power) and self.blur_power > 0):
            raise ConfigError(f"lens effects {self.name!r}: blur_power must be > 0, got {self.blur_power!r}")
        for e in self.exposures:
            if not (e.gain > 0 and e.gamma > 0 and e.defocus_px >= 0 and math.isfinite(e.gain + e.gamma)):
                raise ConfigError(f"lens effects {self.name!r}: bad camera exposure {e}")

    def exposure(self, camera_index: int) -> CameraExposure:
        """The settings of the rig's ``camera_index``-th camera."""
        return self.exposures[camera_index % len(self.exposures)] if self.exposures else CameraExposure()

    def sigma_px(self, x: F64, camera_index: int = 0) -> F64:
        """The PSF's σ (pixels) at relative field ``x`` = θ/θmax for that camera."""
        optics = self.blur_centre_px + self.blur_rim_px * np.clip(x, 0.0, 1.0) ** self.blur_power
        return np.hypot(optics, self.exposure(camera_index).defocus_px)

    def relative_illumination(self, x: F64) -> F64:
        """Brightness factor at relative field ``x`` (1 on the axis)."""
        x2 = np.clip(x, 0.0, 1.0) ** 2
        out = np.ones_like(x2)
        for power, c in enumerate(self.illumination, start=1):
            out += c * x2**power
        return np.maximum(out, 0.0)

    def scaled(self, factor: float) -> LensEffects:
        """The same optics on a sensor scaled by ``factor``: every σ in its pixels scales."""
        return replace(
            self,
            blur_centre_px=self.blur_centre_px * factor,
            blur_rim_px=self.blur_rim_px * factor,
            exposures=tuple(replace(e, defocus_px=e.defocus_px * factor) for e in self.exposures),
        )

    def noiseless(self) -> LensEffects:
        """The same optics and exposures without sensor noise."""
        return replace(self, read_noise=0.0, shot_noise=0.0)


IDEAL_LENS = LensEffects()

#: Fitted by ``python -m bench.lens_fit`` on real fisheye images (docs/evaluation.md).
HONEST_LENS = LensEffects(
    name="honest",
    blur_centre_px=0.5,
    blur_rim_px=1.5,
    blur_power=2.0,
    illumination=(-0.3,),
    read_noise=1.0,
    shot_noise=0.05,
    exposures=(CameraExposure(1.0, 1.0, 0.3), CameraExposure(0.93, 1.05, 0.5)),
)


def blur_by_field(image: F32, sigma: F64) -> F32:
    """``image`` (H, W, C) float32 blurred with a Gaussian of σ ``sigma`` (H, W) pixels that
    varies per pixel: a blend of the image blurred at levels SIGMA_STEP_PX apart, weighted so
    each pixel's blend has the variance σ²."""
    lo, hi = float(sigma.min()), float(sigma.max())
    if hi <= 0.0:
        return image
    steps = max(1, math.ceil((hi - lo) / SIGMA_STEP_PX))
    levels = np.linspace(lo, hi, steps + 1)
    # Each pixel's two levels and the weight of the upper one, in variance.
    k = np.clip(np.searchsorted(levels, sigma, side="right") - 1, 0, steps - 1)
    var_lo, var_hi = levels[k] ** 2, levels[k + 1] ** 2
    upper = np.clip((sigma**2 - var_lo) / np.maximum(var_hi - var_lo, 1e-12), 0.0, 1.0).astype(np.float32)
    out = np.zeros_like(image)
    for level, s in enumerate(levels):
        weight = np.where(k == level, 1.0 - upper, 0.0) + np.where(k + 1 == level, upper, 0.0)
        if weight.any():
            out += _gaussian(image, float(s)) * weight.astype(np.float32)[:, :, None]
    return out


def _gaussian(image: F32, sigma: float) -> F32:
    if sigma <= 0.0:
        return image
    radius = max(1, math.ceil(4.0 * sigma))
    out = cv2.GaussianBlur(image, (2 * radius + 1, 2 * radius + 1), sigma, borderType=cv2.BORDER_REFLECT)
    return np.asarray(out, dtype=np.float32).reshape(image.shape)


def apply_lens(
    shade: F32,
    cos_theta: F64,
    max_theta: float,
    lens: LensEffects,
    camera_index: int,
    rng: np.random.Generator,
) -> F32:
    """``shade`` (H, W, C) float32 grey levels as the lens and sensor ``lens`` make it for the
    rig's ``camera_index``-th camera (module docstring), before rounding to 8 bits.
    ``cos_theta`` (H, W): the cosine of each pixel's angle off the axis; ``max_theta``: the
    lens's field limit (radians); ``rng`` draws the noise."""
    x = np.arccos(np.clip(cos_theta, -1.0, 1.0)) / max_theta
    out = blur_by_field(shade, lens.sigma_px(x, camera_index))
    exposure = lens.exposure(camera_index)
    out = out * (lens.relative_illumination(x) * exposure.gain).astype(np.float32)[:, :, None]
    if lens.read_noise > 0 or lens.shot_noise > 0:
        std = np.sqrt(lens.read_noise**2 + lens.shot_noise * np.maximum(out, 0.0))
        out += std * rng.standard_normal(out.shape, dtype=np.float32)
    if exposure.gamma != 1.0:
        out = 255.0 * (np.clip(out, 0.0, 255.0) / 255.0) ** np.float32(1.0 / exposure.gamma)
    return out.astype(np.float32, copy=False)
