"""A small rendered ring for the tests of rings of N cameras: ring4 (rig.sim.presets) at a
fraction of its size, a few sets of the demo room with the exact range of every pair and of the
panorama (rig.sim.ring_recording), and the coarse rectified pair it is rendered for."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rig.rectified import RectifiedPairConfig
from rig.sim.presets import Preset, get_ring_preset
from rig.sim.ring_recording import simulate_ring_recording
from service.settings import Settings, load_settings
from tests.helpers.recordings import FAST_SUPERVISOR
from tests.helpers.service import TOKEN

__all__ = [
    "IDEAL_LENS_ARGS",
    "SMALL_RING_CONFIG",
    "SMALL_RING_PANORAMA_PX_PER_DEG",
    "ring_service_settings",
    "small_ring_preset",
    "write_small_ring",
]

#: ``rig sim --rig ring4``'s options for the ideal lens with the preset's simple sensor model (its
#: noise and vignetting): the renders the ring tests' figures were measured on (docs/ring.md).
IDEAL_LENS_ARGS = (
    "--lens", "ideal",
    "--noise", f"{get_ring_preset('ring4').noise_std:g}",
    "--vignetting", f"{get_ring_preset('ring4').vignetting:g}",
)  # fmt: skip
#: The rectified pair of the small ring's tests: coarse, so each pair is a few hundred pixels.
SMALL_RING_CONFIG = RectifiedPairConfig(px_per_deg=2.5)
#: Its panorama's resolution (the renderer's exact panorama and the pipeline's).
SMALL_RING_PANORAMA_PX_PER_DEG = 2.0
_SCALE = 0.4


def small_ring_preset() -> Preset:
    return get_ring_preset("ring4").scaled(_SCALE)


def write_small_ring(out: Path, frames: int = 2) -> Path:
    """The small ring's recording at ``out`` (``frames`` sets, no supersampling): the ideal lens
    with the preset's simple sensor model (noise, vignetting), as the ring tests' figures were
    measured."""
    preset = small_ring_preset()
    return simulate_ring_recording(
        preset,
        out,
        frames=frames,
        supersample=1,
        vpc=SMALL_RING_CONFIG,
        panorama_px_per_deg=SMALL_RING_PANORAMA_PX_PER_DEG,
        lens="ideal",
        noise_std=preset.noise_std,
        vignetting=preset.vignetting,
    )


def ring_service_settings(recording: Path, tmp: Path, lut_cache: Path, **server: Any) -> Settings:
    """A service on the four cameras of the small ring's ``recording`` (file cameras ``cam1`` to
    ``cam4``, looping, live timestamps) and its panorama's resolution, with a token, recordings
    under ``tmp/recordings`` and LUTs in ``lut_cache``; ``server`` adds ``server:`` fields."""
    camera = {"kind": "file", "recording": str(recording), "pace": 5.0, "loop": True, "timestamps": "live"}
    return load_settings(
        None,
        {
            "server": {"recordings_dir": str(tmp / "recordings"), "api_token": TOKEN, **server},
            "cameras": {
                "rig": {f"cam{k}": {**camera, "camera": f"cam{k}"} for k in range(1, 5)},
                "supervisor": FAST_SUPERVISOR.model_dump(),
            },
            "rectified": SMALL_RING_CONFIG.model_dump(),
            "panorama": {"px_per_deg": SMALL_RING_PANORAMA_PX_PER_DEG},
            "cache_dir": str(lut_cache),
        },
    )
