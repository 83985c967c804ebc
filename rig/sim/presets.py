"""Simulated rigs: the paper's virtual rig and our prototype (docs/evaluation.md).

``paper-sim``: two identical ideal 180° equidistant lenses, 20 cm baseline, 90° between the axes
(the paper's Unity set-up, §IV-B), 1024×1024 with the image circle inscribed.

``prototype``: 190° lenses (1.45 mm, AC123B0145IRM12MM) at 1280×960 in a 90° mount, ~72 mm
baseline. Kannala-Brandt coefficients from the paper's Table II (CamOdoCal k2..k5 = our k1..k4);
the paper gives no focal length: fx ≈ 297 px puts 95° at ~485 px, so the lens circle is cut off
at the top (left camera) or bottom (right camera) and sits slightly off-centre, as in its Fig. 9.

Rings (:data:`RING_PRESETS`, cameras ``cam1``..``camN``): ``ring4``, four prototype lenses (its
left and right lens in turn) at 90° on the corners of a 72 mm square, looking out through them:
every adjacent pair is the prototype's pair, baseline and angle.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, replace

from calibration.models import CameraModel, create
from calibration.rig import Rig
from rig.errors import ConfigError
from rig.sim.lens_effects import HONEST_LENS, LensEffects
from rig.sim.mount import divergent_rig, ring_rig

__all__ = ["PRESETS", "RING_PRESETS", "Preset", "get_preset", "get_ring_preset", "scale_camera"]


@dataclass(frozen=True)
class Preset:
    """A simulated rig: cameras "left"/"right" (a ring's: ``cam1``..``camN``), frame rate, the
    honest renderer's ``lens`` effects (:mod:`rig.sim.lens_effects`, fitted to real fisheyes) and
    the simple sensor model of the renders before it (``noise_std`` grey levels, ``vignetting``
    strength), which the demo's and the benchmarks' frames still add to a noise-free render."""

    name: str
    rig: Rig
    fps: float
    description: str
    noise_std: float = 0.0
    vignetting: float = 0.0
    lens: LensEffects = HONEST_LENS

    def scaled(self, factor: float) -> Preset:
        """The same rig with every camera's image scaled by ``factor`` (quick renders, tests)."""
        cams = {n: scale_camera(c, factor) for n, c in self.rig.cameras.items()}
        rig = Rig(cams, {n: T.copy() for n, T in self.rig.T_rig_cam.items()}, self.rig.pairs)
        return replace(self, rig=rig, lens=self.lens.scaled(factor))


def scale_camera(camera: CameraModel, factor: float) -> CameraModel:
    """``camera`` resampled to ``factor`` × its size: fx, fy scale, and the principal point keeps
    its place relative to the pixel edges (pixel (0, 0) is a pixel centre, docs/design.md)."""
    f = float(factor)
    if not (math.isfinite(f) and 0.01 <= f <= 8.0):
        raise ConfigError(f"camera scale factor must be in [0.01, 8], got {factor!r}")
    if f == 1.0:
        return camera
    p = camera.param_dict
    if not {"fx", "fy", "cx", "cy"} <= set(p):
        raise ConfigError(f"cannot scale a {camera.name} camera: it has no fx, fy, cx, cy")
    w, h = max(2, round(camera.width * f)), max(2, round(camera.height * f))
    sx, sy = w / camera.width, h / camera.height
    return camera.replace(
        width=w,
        height=h,
        fx=p["fx"] * sx,
        fy=p["fy"] * sy,
        cx=(p["cx"] + 0.5) * sx - 0.5,
        cy=(p["cy"] + 0.5) * sy - 0.5,
    )


def _paper_sim() -> Preset:
    size = 1024
    f = size / math.pi  # 90° off axis lands on the image edge: the 180° circle is inscribed
    c = (size - 1) / 2.0
    lens = create("equidistant", size, size, fx=f, fy=f, cx=c, cy=c, fov_deg=180.0)
    return Preset(
        "paper-sim",
        divergent_rig(lens, lens.replace(), 0.20, 90.0),
        30.0,
        "paper's virtual rig: two ideal 180° equidistant lenses, 1024x1024, 20 cm baseline, 90° apart",
    )


def _prototype_lenses() -> tuple[CameraModel, CameraModel]:
    left = create(
        "kannala_brandt", 1280, 960, fx=298.0, fy=298.0, cx=651.0, cy=471.0,
        k1=3.78e-4, k2=4.48e-5, k3=5.79e-3, k4=-2.41e-3, fov_deg=190.0,
    )  # fmt: skip
    right = create(
        "kannala_brandt", 1280, 960, fx=297.0, fy=297.0, cx=628.5, cy=489.0,
        k1=3.80e-4, k2=1.89e-3, k3=-1.20e-3, k4=-1.22e-4, fov_deg=190.0,
    )  # fmt: skip
    return left, right


def _prototype() -> Preset:
    left, right = _prototype_lenses()
    return Preset(
        "prototype",
        divergent_rig(left, right, 0.072, 90.0),
        30.0,
        "our prototype: 190° Kannala-Brandt lenses (paper Table II), 1280x960, 72 mm baseline, 90° apart",
        noise_std=1.5,
        vignetting=0.35,
    )


def _ring4() -> Preset:
    left, right = _prototype_lenses()
    return Preset(
        "ring4",
        ring_rig([left, right, left.replace(), right.replace()], 0.072),
        30.0,
        "four prototype lenses at 90° on the corners of a 72 mm square, looking out",
        noise_std=1.5,
        vignetting=0.35,
    )


#: Every two-camera preset by name. :func:`get_preset` hands out independent copies.
PRESETS: dict[str, Preset] = {p.name: p for p in (_paper_sim(), _prototype())}
#: The rings of N cameras (``cam1``..``camN``) by name; :func:`get_ring_preset` hands out copies.
RING_PRESETS: dict[str, Preset] = {p.name: p for p in (_ring4(),)}


def get_preset(name: str) -> Preset:
    """A fresh copy of preset ``name``; ConfigError listing the valid names otherwise."""
    try:
        return copy.deepcopy(PRESETS[name])
    except (KeyError, TypeError):
        raise ConfigError(f"unknown preset {name!r}; valid presets: {', '.join(PRESETS)}") from None


def get_ring_preset(name: str) -> Preset:
    """A fresh copy of ring preset ``name``; ConfigError listing the valid names otherwise."""
    try:
        return copy.deepcopy(RING_PRESETS[name])
    except (KeyError, TypeError):
        raise ConfigError(f"unknown ring {name!r}; valid rings: {', '.join(RING_PRESETS)}") from None
