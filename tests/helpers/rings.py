"""A small rendered ring for the tests of rings of N cameras: ring4 (rig.sim.presets) at a
fraction of its size, a few sets of the demo room with the exact range of every pair and of the
panorama (rig.sim.ring_recording), and the coarse rectified pair it is rendered for."""

from __future__ import annotations

from pathlib import Path

from rig.rectified import RectifiedPairConfig
from rig.sim.presets import Preset, get_ring_preset
from rig.sim.ring_recording import simulate_ring_recording

__all__ = ["SMALL_RING_CONFIG", "small_ring_preset", "write_small_ring"]

#: The rectified pair of the small ring's tests: coarse, so each pair is a few hundred pixels.
SMALL_RING_CONFIG = RectifiedPairConfig(px_per_deg=2.5)
_SCALE = 0.4


def small_ring_preset() -> Preset:
    return get_ring_preset("ring4").scaled(_SCALE)


def write_small_ring(out: Path, frames: int = 2) -> Path:
    """The small ring's recording at ``out`` (``frames`` sets, no supersampling)."""
    return simulate_ring_recording(
        small_ring_preset(), out, frames=frames, supersample=1, vpc=SMALL_RING_CONFIG, panorama_px_per_deg=2.0
    )
