"""What a real fisheye and its sensor do to the ideal image: the honest renderer's lens model.

Applied to the renderer's box-filtered image (grey levels, linear in the scene's radiance), per
pixel of field angle θ off the optical axis (x = θ / θmax, θmax the lens's field limit):

1. **Sharpness falling with field angle, and defocus**: a Gaussian PSF of
   ``σ(x) = hypot(σ0 + σ1·x^p, defocus)`` pixels. Done as a blend of a few images blurred at
   fixed σ (steps of at most :data:`SIGMA_STEP_PX`), each pixel mixing the two levels either
   side of its σ with the weights that give the mix exactly the variance σ² (a mix of two
   Gaussians this close is Gaussian-shaped to well under a grey level).
2. **Rim darkening** (relative illumination): ``× (1 + c1·x² + c2·x⁴ + …)``.
3. **Exposure and response** (per camera): ``v → gain · m · (v / m)^γ`` about the pivot grey
   level m: the camera's brightness at m relative to the others', and the slope of its response.
4. **Sensor noise**: gaussian with variance ``read² + shot·v`` grey levels² at output level v
   (what a camera's images show; the shot part is its photon noise), seeded; then rounding to
   8 bits (by the renderer).

The curves are functions of the relative field x, so one fit serves lenses of any field; σ is in
the lens's own pixels. :data:`HONEST_LENS` holds the parameters fitted to real fisheye images
(``python -m bench.lens_fit``; docs/evaluation.md, "The honest renderer"); :data:`IDEAL_LENS`
turns everything off.
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
    "check_lens",
    "lens_for",
]

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

#: The largest σ step between two pre-blurred levels (pixels).
SIGMA_STEP_PX = 0.25
#: ``rig sim --lens`` choices.
LENS_CHOICES = ("honest", "ideal")


@dataclass(frozen=True)
class CameraExposure:
    """One camera's own settings: ``gain`` (its brightness at the pivot grey level, relative),
    ``gamma`` (the slope of its response in log-log) and ``defocus_px``, a constant Gaussian σ
    added in quadrature."""

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
    response_pivot: float = 128.0
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
        if not (math.isfinite(self.response_pivot) and 0 < self.response_pivot <= 255):
            raise ConfigError(
                f"lens effects {self.name!r}: response_pivot must be in (0, 255], got {self.response_pivot!r}"
            )
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

    def describe(self, cameras: int = 2) -> str:
        """One sentence for reports: what these effects do to ``cameras`` cameras."""
        if self == replace(IDEAL_LENS, name=self.name):
            nothing = "no blur beyond the pixel, no rim darkening, no exposure differences, no noise"
            return f"{self.name} lens: {nothing}"
        sigma = self.sigma_px(np.array([0.0, 1.0]))
        per = [self.exposure(i) for i in range(cameras)]

        def each(values: list[float], digits: int) -> str:
            return " / ".join(f"{v:.{digits}f}" for v in values)

        rim = float(self.relative_illumination(np.array(1.0)))
        return (
            f"{self.name} lens (rig.sim.lens_effects): PSF σ {sigma[0]:.2f} → {sigma[1]:.2f} px from the "
            f"axis to the field edge, defocus {each([e.defocus_px for e in per], 2)} px, relative "
            f"illumination {rim:.2f} at the field edge, gains {each([e.gain for e in per], 3)} and γ "
            f"{each([e.gamma for e in per], 3)} about grey {self.response_pivot:g}, noise σ² = "
            f"{self.read_noise:.2f}² + {self.shot_noise:g}·grey"
        )

    def noiseless(self) -> LensEffects:
        """The same optics and exposures without sensor noise."""
        return replace(self, read_noise=0.0, shot_noise=0.0)

    def sensor_only(self) -> LensEffects:
        """The sensor noise alone (an ideal lens on the same sensor: a Reference view)."""
        return replace(
            IDEAL_LENS, name=f"{self.name} sensor", read_noise=self.read_noise, shot_noise=self.shot_noise
        )

    def reach_px(self, camera_index: int = 0) -> int:
        """How far (pixels) the blur reaches: a crop rendered this much larger than needed
        blurs its needed part as the whole image would."""
        sigma = float(np.max(self.sigma_px(np.linspace(0.0, 1.0, 65), camera_index)))
        return math.ceil(4.0 * sigma) + 1 if sigma > 0 else 0


IDEAL_LENS = LensEffects()

#: Fitted by ``python -m bench.lens_fit`` to the real ring's images (docs/evaluation.md): the
#: ring's shared blur curve, rim darkening, pivot and median noise; the two cameras take the
#: defocus, relative gain and γ of its cameras 1 and 2, an adjacent pair.
HONEST_LENS = LensEffects(
    name="honest",
    blur_centre_px=0.562,
    blur_rim_px=0.274,
    blur_power=2.0,
    illumination=(-0.0834, -0.2309),
    response_pivot=98.3,
    read_noise=0.804,
    shot_noise=0.0006,
    exposures=(CameraExposure(0.948, 1.0, 0.0), CameraExposure(1.052, 1.075, 0.705)),
)


def check_lens(choice: str) -> str:
    """``choice`` if it is one of :data:`LENS_CHOICES`; ConfigError naming them otherwise."""
    if choice not in LENS_CHOICES:
        raise ConfigError(f"unknown lens {choice!r}; valid: {', '.join(LENS_CHOICES)}")
    return choice


def lens_for(choice: str, honest: LensEffects) -> LensEffects:
    """The effects for a ``--lens`` choice: ``honest`` (the preset's fitted ``honest``) or
    ``ideal`` (none)."""
    return honest if check_lens(choice) == "honest" else IDEAL_LENS


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
    out = out * lens.relative_illumination(x).astype(np.float32)[:, :, None]
    exposure = lens.exposure(camera_index)
    if exposure.gain != 1.0 or exposure.gamma != 1.0:
        pivot = np.float32(lens.response_pivot)
        response = exposure.gain * pivot * (np.maximum(out, 0.0) / pivot) ** np.float32(exposure.gamma)
        out = np.asarray(response, dtype=np.float32)
    if lens.read_noise > 0 or lens.shot_noise > 0:
        std = np.sqrt(lens.read_noise**2 + lens.shot_noise * np.maximum(out, 0.0))
        out = np.asarray(out + std * rng.standard_normal(out.shape, dtype=np.float32), dtype=np.float32)
    return np.asarray(out, dtype=np.float32)
