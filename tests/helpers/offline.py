"""Small recordings for the offline-processing tests (rig.process, rig.cluster, rig process): a
rendered plane at 320×240, each pair with its own sensor noise (so that consecutive depth maps
differ and the temporal filter has a history that matters), and helpers comparing output trees
byte for byte."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibration import save_rig
from rig.pipeline import DepthPipeline
from rig.recording import RecordingWriter
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams
from tests.helpers.shots import StereoShot, plane_shot

__all__ = [
    "STEREO",
    "TEMPORAL",
    "VPC",
    "VPC_ARGS",
    "files_of",
    "make_pipeline",
    "noisy_recording",
    "shot",
]

VPC = RectifiedPairConfig(width=320, height=240)
VPC_ARGS = ["--vpc-size", "320x240", "--vpc-hfov", "90"]
# At 320 px wide, 64 disparities (128 would leave 40 % of the columns unmatched).
STEREO = StereoParams(disparity_range=64)
TEMPORAL = StereoParams(disparity_range=64, temporal_alpha=0.6, temporal_reset=2.0)


def shot() -> StereoShot:
    return plane_shot(5.0, scale=0.5, vpc=VPC)


def noisy_recording(root: Path, n: int, *, seed: int = 0, first_seq: int = 0) -> Path:
    """A recording of ``n`` pairs of the plane, each with fresh noise (σ 4 grey levels), PNG
    frames, the rig as ``rig.yaml`` and the stereo settings as ``stereo.yaml`` and
    ``temporal.yaml``."""
    s = shot()
    rng = np.random.default_rng(seed)
    with RecordingWriter(root, meta={"generator": "tests"}) as writer:
        for k in range(n):
            seq = first_seq + k
            left, right = (
                np.clip(img + rng.normal(0.0, 4.0, img.shape), 0, 255).astype(np.uint8)
                for img in (s.left, s.right)
            )
            writer.write_images(seq, seq * 1000, seq * 1000 + 5, left, right)
    save_rig(s.rig, root / "rig.yaml")
    (root / "stereo.yaml").write_text("disparity_range: 64\n")
    (root / "temporal.yaml").write_text("disparity_range: 64\ntemporal_alpha: 0.6\ntemporal_reset: 2.0\n")
    return root


def make_pipeline(stereo: StereoParams, cache: Path) -> DepthPipeline:
    return DepthPipeline(shot().rig, VPC, stereo, cache_dir=cache)


def files_of(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` by relative path, with its bytes."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}
