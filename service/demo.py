"""The embedded demo: a rendered room recording replayed by file cameras, so ``rig serve --demo``
shows live depth with no hardware.

The first run renders the demo room once with the virtual environment (:mod:`rig.sim`, the
``prototype`` rig: 190° Kannala-Brandt lenses, 72 mm baseline) into the user cache directory,
keyed by a hash of everything that determines it, then adds fresh sensor noise to each of
``frames`` copies of that view: a static scene whose depth visibly lives, looping seamlessly at
30 fps. The render goes into a temporary directory that is renamed into place only when
complete (:func:`calibration.atomic.atomic_directory`), so an interrupted render is never used
(its leftovers are removed next time).
"""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import platformdirs

from calibration.atomic import atomic_directory
from rig.recording import RECORDING_VERSION, Recording, RecordingWriter
from rig.rectified import RectifiedPairConfig
from rig.sim import get_preset, simulate_recording
from rig.sim.simulate import GROUND_TRUTH_VERSION

__all__ = [
    "DEMO_FPS",
    "DEMO_VERSION",
    "DemoSpec",
    "cached_demo_recording",
    "demo_cache_dir",
    "demo_key",
    "demo_overrides",
    "ensure_demo_recording",
    "render_demo",
    "replay_overrides",
]

DEMO_VERSION = 1
DEMO_FPS = 30.0
#: ``progress(step, done, total)``: step is "render" (0/1 → 1/1) or "noise" (k of frames).
StepProgress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class DemoSpec:
    """What the demo recording is made of; every field is part of its cache key."""

    preset: str = "prototype"
    scale: float = 1.0
    frames: int = 30
    supersample: int = 2
    seed: int = 0
    vpc: RectifiedPairConfig = field(default_factory=RectifiedPairConfig)
    lens: str = "honest"  # rig sim's lens effects (its noise is left to the loop's frames)

    def as_json(self) -> dict[str, Any]:
        return {
            "demo_version": DEMO_VERSION,
            "ground_truth_version": GROUND_TRUTH_VERSION,
            "recording_version": RECORDING_VERSION,
            "preset": self.preset,
            "scale": self.scale,
            "frames": self.frames,
            "supersample": self.supersample,
            "seed": self.seed,
            "vpc": self.vpc.model_dump(mode="json"),
            "lens": self.lens,
        }


def demo_cache_dir() -> Path:
    """``<user cache dir>/odfc-rig/demo`` (honours ``XDG_CACHE_HOME`` on Linux)."""
    return Path(platformdirs.user_cache_dir("odfc-rig")) / "demo"


def demo_key(spec: DemoSpec) -> str:
    doc = json.dumps(spec.as_json(), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(doc.encode()).hexdigest()[:16]


def render_demo(spec: DemoSpec, out: Path, progress: StepProgress | None = None) -> Path:
    """Render the demo into ``out`` (new): ``out/render`` is the noise-free rendered recording
    with ground truth, ``out/loop`` the replayed recording (``frames`` noisy pairs and the rig's
    calibration.yaml). Returns ``out/loop``."""
    preset = get_preset(spec.preset)
    if spec.scale != 1.0:
        preset = preset.scaled(spec.scale)
    render_dir = out / "render"
    if progress is not None:
        progress("render", 0, 1)
    simulate_recording(
        preset,
        "room",
        render_dir,
        frames=1,
        noise_std=0.0,
        supersample=spec.supersample,
        seed=spec.seed,
        vpc=spec.vpc,
        lens=spec.lens,
    )
    if progress is not None:
        progress("render", 1, 1)
    source = Recording(render_dir)
    base = {cam: source.read_image(source.pairs[0], cam).astype(np.float32) for cam in ("left", "right")}
    period_ns = round(1e9 / DEMO_FPS)
    loop_dir = out / "loop"
    rng = np.random.default_rng(np.random.SeedSequence([spec.seed, DEMO_VERSION]))
    meta = {"generator": "rig serve --demo", "demo": spec.as_json(), "fps": DEMO_FPS, "scene": "room"}
    with RecordingWriter(loop_dir, meta=meta) as writer:
        for k in range(spec.frames):
            noisy = [
                np.clip(
                    np.rint(base[cam] + rng.normal(0.0, preset.noise_std, base[cam].shape)), 0, 255
                ).astype(np.uint8)
                for cam in ("left", "right")
            ]
            ts = k * period_ns
            writer.write_images(k, ts, ts, noisy[0], noisy[1])
            if progress is not None:
                progress("noise", k + 1, spec.frames)
    shutil.copyfile(render_dir / "calibration.yaml", loop_dir / "calibration.yaml")
    return loop_dir


def cached_demo_recording(spec: DemoSpec | None = None, cache_dir: Path | None = None) -> Path | None:
    """The demo's loop recording if it has been rendered already, else None."""
    loop = (cache_dir or demo_cache_dir()) / demo_key(spec or DemoSpec()) / "loop"
    return loop if (loop / "frames.csv").is_file() else None


def ensure_demo_recording(
    spec: DemoSpec | None = None, cache_dir: Path | None = None, *, progress: StepProgress | None = None
) -> Path:
    """The demo's loop recording, rendered on first use (reporting to ``progress``)."""
    spec = spec or DemoSpec()
    cache = cache_dir or demo_cache_dir()
    cached = cached_demo_recording(spec, cache)
    if cached is not None:
        return cached
    final = cache / demo_key(spec)
    cache.mkdir(parents=True, exist_ok=True)
    with atomic_directory(final, complete=_rendered) as tmp:
        render_demo(spec, tmp, progress)
        (tmp / "demo.json").write_text(json.dumps(spec.as_json(), indent=2) + "\n")
    return final / "loop"


def _rendered(directory: Path) -> bool:
    return (directory / "loop" / "frames.csv").is_file()


def replay_overrides(
    recording: Path,
    calibration: Path,
    pace: float | str,
    source: Mapping[str, Any] | None = None,
    cameras: Sequence[str] = ("left", "right"),
) -> dict[str, Any]:
    """Settings overrides: file cameras replaying ``recording`` at ``pace`` (fps or
    ``"recorded"``), looping with live timestamps, and ``calibration`` for the rig. ``source``:
    more file-camera fields (a bag's ``left_topic``, ``right_topic``, ``max_skew_ms``, or
    ``topics``); ``cameras``: the recording's (other than ``left``, ``right``: ``cameras.rig``)."""
    camera = {
        "kind": "file",
        "recording": str(recording),
        "pace": pace,
        "loop": True,
        "timestamps": "live",
        **(source or {}),
    }
    named = {name: {**camera, "camera": name} for name in cameras}
    section = named if list(cameras) == ["left", "right"] else {"rig": named}
    return {"cameras": section, "calibration": {"path": str(calibration)}}


def demo_overrides(loop_recording: Path, fps: float = DEMO_FPS) -> dict[str, Any]:
    """:func:`replay_overrides` of the demo recording with its own calibration."""
    return replay_overrides(loop_recording, loop_recording / "calibration.yaml", fps)
