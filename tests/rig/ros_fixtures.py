"""A tiny rendered recording and its pipeline, shared by the ROS / MCAP tests (small VPC, few pairs)."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from rig.pipeline import DepthPipeline
from rig.recording import RecordingWriter
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams
from tests.helpers.shots import StereoShot, plane_shot

VPC = RectifiedPairConfig(width=160, height=120)
STEREO = StereoParams(disparity_range=32)
PAIRS = 3
T0_NS = 1_700_000_000_123_456_789  # an epoch-like stamp, to catch sec/nanosec splits
PERIOD_NS = 33_333_333
SKEW_NS = 2_000_000


@functools.lru_cache(maxsize=1)
def shot() -> StereoShot:
    return plane_shot(5.0, scale=0.25, vpc=VPC)


@dataclass(frozen=True)
class TinyRecording:
    root: Path
    jpegs: list[tuple[bytes, bytes]]
    stamps: list[tuple[int, int]]


def write_jpeg_recording(root: Path, pairs: int = PAIRS) -> TinyRecording:
    """``pairs`` JPEG pairs of the plane shot (each with a little noise, so they differ)."""
    s = shot()
    rng = np.random.default_rng(0)
    jpegs, stamps = [], []
    with RecordingWriter(root, meta={"generator": "test"}) as w:
        for seq in range(pairs):
            frames = []
            for img in (s.left, s.right):
                noisy = np.clip(img.astype(np.int16) + rng.integers(-2, 3, img.shape), 0, 255).astype(
                    np.uint8
                )
                frames.append(cv2.imencode(".jpg", noisy)[1].tobytes())
            lts = T0_NS + seq * PERIOD_NS
            rts = lts + SKEW_NS
            w.write_pair(seq, lts, rts, frames[0], frames[1])
            jpegs.append((frames[0], frames[1]))
            stamps.append((lts, rts))
    return TinyRecording(root, jpegs, stamps)


def pipeline(cache: Path) -> DepthPipeline:
    return DepthPipeline(shot().rig, VPC, STEREO, cache_dir=cache)
