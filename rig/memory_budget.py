"""How much memory the depth pipeline will need, estimated from its settings before anything is
built, and whether the machine has it.

A rectified pair or camera size that cannot fit must be refused at start-up with the reason, not discovered
as gigabytes of RSS while health says ok. :func:`pipeline_parts` adds up, per part, the arrays the
pipeline keeps or makes per frame (bytes per rectified pixel ``P``, per camera pixel ``C``, times the
frames alive at once); the service adds its own parts (:mod:`service.memory`). The figures are
upper bounds of what each part holds at its peak, so that the sum is a budget the process's
resident size stays under (docs/reliability.md, "Memory budget", compares them with measured RSS).

The parts, per frame alive (:data:`FRAMES_ALIVE`: one in each of the worker's three stages, the
published result, the previous one the worker prefetches from, one a client still sends):

- rectified arrays: gray pair 2, colour pair 6, disparity, depth and confidence float32 12, valid 1,
  the matcher's int16 output 2, encoded bodies (PNG, npy, JPEG of depth, disparity, confidence)
  up to 17 bytes per ``P``;
- the raw camera frames behind them: stored bytes, gray and colour decodes, 5 bytes per ``C`` and
  camera;

and once: the lookup tables (float maps 8, fixed-point maps 6, mask 1 byte per ``P`` and camera),
the matcher's buffers (SGBM: ``32·W·D`` per thread; its full 8-path mode keeps the whole cost
volume, ``4·P·D``), the finish stage's temporaries (60 bytes per ``P``), the temporal prior's
history (5 bytes per ``P``), and the frames waiting
in the capture's buffers (``buffer_size + pair_buffer`` per camera, raw and gray: 2 bytes per
``C``).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from rig.stereo import StereoParams

__all__ = [
    "FRAMES_ALIVE",
    "MemoryEstimate",
    "available_memory",
    "pipeline_parts",
    "ring_parts",
]

FRAMES_ALIVE = 6
_RECT_BYTES_PER_FRAME = 2 + 6 + 12 + 1 + 2 + 17
_CAMERA_BYTES_PER_FRAME = 5
_LUT_BYTES = 8 + 6 + 1
_FINISH_TEMPORARIES = 60
# The live stream's temporal prior (rig.temporal_prior): the kept search's two int16 views and the
# pair at 2x2 block means (the coarse-to-fine search keeps less: float32 fields at a quarter).
_PRIOR_BYTES = 2 + 2 + 1
_SGBM_THREAD_BYTES_PER_WD = 32
_QUEUED_FRAME_BYTES = 2
# A ring's panorama, per pixel: per frame alive its range, sigma (float32), source, flags and
# samples (uint8) and its PNG and npy bodies; once, its rays (3 float64) and each pair's
# far-field pixels of them (an index and two float64, for the share a pair sees: at most all);
# while fusing, per pair two float64 and five more of the fusion's (P, K) arrays.
_PANORAMA_BYTES_PER_FRAME = 4 + 4 + 1 + 1 + 1 + 2 + 4
_PANORAMA_RAYS = 24
_PANORAMA_FAR_FIELD_PER_PAIR = 24
_PANORAMA_FUSION_PER_PAIR = 7 * 8
MIB = 1 << 20


@dataclass(frozen=True)
class MemoryEstimate:
    """Bytes per part (insertion order = the order they are reported in)."""

    parts: dict[str, int] = field(default_factory=dict)

    @property
    def total(self) -> int:
        return sum(self.parts.values())

    def plus(self, **more: int) -> MemoryEstimate:
        return MemoryEstimate({**self.parts, **more})

    def largest(self, n: int = 3) -> str:
        """``name X MiB, ...`` of the ``n`` largest parts."""
        top = sorted(self.parts.items(), key=lambda kv: -kv[1])[:n]
        return ", ".join(f"{name.replace('_', ' ')} {size / MIB:.0f} MiB" for name, size in top)


def pipeline_parts(
    rectified_size: tuple[int, int],
    stereo: StereoParams,
    camera_sizes: Sequence[tuple[int, int]],
    *,
    queued_frames_per_camera: int = 12,
    threads: int | None = None,
) -> MemoryEstimate:
    """The pipeline's parts for a rectified pair of ``rectified_size`` (w, h) (the designed
    pair's, :attr:`rig.in_effect.PairInEffect.camera`, or :func:`rig.rectified.design_rectified_pair`'s
    before a pipeline is built), ``stereo`` and cameras of ``camera_sizes`` (w, h)."""
    width, height = rectified_size
    p = width * height
    c = sum(w * h for w, h in camera_sizes)
    d = stereo.disparity_range
    threads = threads or os.cpu_count() or 1
    if stereo.stereo_algorithm == 1 and stereo.effective_mode == "hh":
        matcher = 4 * p * d  # the whole cost volume, 16-bit, twice
    else:
        matcher = _SGBM_THREAD_BYTES_PER_WD * width * d * threads
    return MemoryEstimate(
        {
            "lookup_tables": 2 * _LUT_BYTES * p,
            "rectified_frames": FRAMES_ALIVE * _RECT_BYTES_PER_FRAME * p,
            "camera_frames": FRAMES_ALIVE * _CAMERA_BYTES_PER_FRAME * c,
            "matcher": matcher + (_FINISH_TEMPORARIES + _PRIOR_BYTES * stereo.temporal_prior) * p,
            "capture_buffers": queued_frames_per_camera * _QUEUED_FRAME_BYTES * c,
        }
    )


def ring_parts(
    pairs: Sequence[tuple[tuple[int, int], tuple[str, str]]],
    stereo: StereoParams,
    camera_sizes: dict[str, tuple[int, int]],
    panorama_size: tuple[int, int],
    *,
    queued_frames_per_camera: int = 12,
    threads: int | None = None,
) -> MemoryEstimate:
    """The parts of a rig of N cameras: ``pairs`` each a rectified size (w, h) and its two
    cameras; every pair has its own tables, rectified frames and matcher (:func:`pipeline_parts`),
    each camera's frames count once however many pairs use them, and the panorama of
    ``panorama_size`` (w, h) adds its frames, rays and the fusion's arrays."""
    parts: dict[str, int] = {}
    for size, _ in pairs:
        one = pipeline_parts(size, stereo, [], queued_frames_per_camera=0, threads=threads).parts
        for name in ("lookup_tables", "rectified_frames", "matcher"):
            parts[name] = parts.get(name, 0) + one[name]
    used = {n for _, names in pairs for n in names}
    c = sum(w * h for n, (w, h) in camera_sizes.items() if n in used)
    q = panorama_size[0] * panorama_size[1]
    parts["camera_frames"] = FRAMES_ALIVE * _CAMERA_BYTES_PER_FRAME * c
    parts["capture_buffers"] = queued_frames_per_camera * _QUEUED_FRAME_BYTES * c
    parts["panorama"] = q * (
        FRAMES_ALIVE * _PANORAMA_BYTES_PER_FRAME
        + _PANORAMA_RAYS
        + len(pairs) * (_PANORAMA_FAR_FIELD_PER_PAIR + _PANORAMA_FUSION_PER_PAIR)
    )
    return MemoryEstimate(parts)


def available_memory(meminfo: Path = Path("/proc/meminfo"), cgroup: Path | None = None) -> int | None:
    """Bytes this process may still take: the kernel's MemAvailable, lowered to the room left
    under a cgroup (v2) limit when it runs in one; None where neither is known."""
    found: list[int] = []
    try:
        for line in meminfo.read_text().splitlines():
            if line.startswith("MemAvailable:"):
                found.append(int(line.split()[1]) * 1024)
    except (OSError, ValueError, IndexError):
        pass
    root = cgroup if cgroup is not None else _own_cgroup()
    if root is not None:
        try:
            limit = (root / "memory.max").read_text().strip()
            if limit != "max":
                used = int((root / "memory.current").read_text().strip())
                found.append(max(0, int(limit) - used))
        except (OSError, ValueError):
            pass
    return min(found) if found else None


def _own_cgroup() -> Path | None:
    try:
        for line in Path("/proc/self/cgroup").read_text().splitlines():
            if line.startswith("0::"):
                return Path("/sys/fs/cgroup") / line[3:].strip().lstrip("/")
    except OSError:
        pass
    return None
