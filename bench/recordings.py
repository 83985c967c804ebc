"""Benchmark input: a recording of MJPEG frames like the real cameras deliver.

The prototype rig (1280×960 Kannala-Brandt 190° lenses) is rendered in the demo room
(:func:`rig.sim.simulate_recording`, noise-free, ``views`` rig poses), then each of ``frames``
pairs gets fresh sensor noise (the preset's σ) and is encoded as a colour JPEG with 4:2:2 chroma
subsampling (what UVC cameras send as MJPEG) at ``quality``. Built once per spec into the bench
cache (a temporary directory renamed into place when complete) and reused.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from bench.common import bench_cache_dir, console
from calibration.atomic import atomic_directory
from rig.recording import Recording, RecordingWriter
from rig.sim import get_preset, simulate_recording

__all__ = ["MjpegSpec", "ensure_mjpeg_recording", "load_jpeg_pairs"]

SPEC_VERSION = 1


@dataclass(frozen=True)
class MjpegSpec:
    """What the recording is made of (every field is part of its cache key). ``scale`` shrinks
    the prototype's 1280×960 lenses (quick runs)."""

    frames: int = 8
    views: int = 2
    quality: int = 90
    scale: float = 1.0
    color: bool = True
    seed: int = 0

    def key(self) -> str:
        doc = json.dumps({"version": SPEC_VERSION, **asdict(self)}, sort_keys=True)
        return hashlib.sha256(doc.encode()).hexdigest()[:16]


def _encode(img: np.ndarray, quality: int) -> bytes:
    params = [cv2.IMWRITE_JPEG_QUALITY, quality]
    if img.ndim == 3:
        params += [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422]
    ok, buf = cv2.imencode(".jpg", img, params)
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return bytes(buf.tobytes())


def _build(spec: MjpegSpec, out: Path) -> None:
    preset = get_preset("prototype")
    if spec.scale != 1.0:
        preset = preset.scaled(spec.scale)
    render_dir = out / "render"
    # The renders the published figures were measured on: the ideal lens, the preset's vignetting.
    simulate_recording(
        preset, "room", render_dir, frames=spec.views, noise_std=0.0, supersample=1, color=spec.color,
        lens="ideal", vignetting=preset.vignetting,
    )  # fmt: skip
    render = Recording(render_dir)
    rng = np.random.default_rng(spec.seed)
    period_ns = round(1e9 / preset.fps)
    loop = out / "loop"
    meta = {"generator": "bench.recordings", "spec": asdict(spec), "fps": preset.fps}
    with RecordingWriter(loop, meta=meta) as writer:
        for k in range(spec.frames):
            pair = render.pairs[k % len(render.pairs)]
            data = []
            for cam in ("left", "right"):
                base = render.read_image(pair, cam, cv2.IMREAD_UNCHANGED).astype(np.float32)
                noisy = np.clip(np.rint(base + rng.normal(0.0, preset.noise_std, base.shape)), 0, 255)
                data.append(_encode(noisy.astype(np.uint8), spec.quality))
            ts = k * period_ns
            writer.write_pair(k, ts, ts, data[0], data[1], ext=".jpg")
    shutil.copyfile(render_dir / "calibration.yaml", loop / "calibration.yaml")
    shutil.rmtree(render_dir)


def ensure_mjpeg_recording(spec: MjpegSpec | None = None, cache_dir: Path | None = None) -> Path:
    """The recording for ``spec`` (built on first use); returns its directory."""
    spec = spec or MjpegSpec()
    cache = (cache_dir or bench_cache_dir()) / "recordings"
    final = cache / spec.key()
    if (final / "loop" / "frames.csv").is_file():
        return final / "loop"
    cache.mkdir(parents=True, exist_ok=True)
    with atomic_directory(final, complete=lambda built: (built / "loop" / "frames.csv").is_file()) as tmp:
        console.print(f"building the benchmark recording {spec} (once; cached under {cache})")
        _build(spec, tmp)
    return final / "loop"


def load_jpeg_pairs(recording: Path) -> list[tuple[bytes, bytes]]:
    """Every pair's encoded bytes (left, right), in recording order."""
    rec = Recording(recording)
    return [(rec.read_bytes(p, "left"), rec.read_bytes(p, "right")) for p in rec.pairs]
