"""Small recordings built on the fly: real JPEG/PNG bytes from cv2.imencode, timestamps on an
exact grid so pairing outcomes are known in advance, and the file-camera configs replaying them."""

from __future__ import annotations

import shutil
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from rig.capture.config import CaptureConfig, FileCameraConfig, PairingConfig, SupervisorConfig
from rig.recording import Recording, RecordingWriter

__all__ = [
    "FAST_SUPERVISOR",
    "PERIOD_NS",
    "T0_NS",
    "encode",
    "file_camera_config",
    "frame_image",
    "jpeg_copy",
    "replay_config",
    "write_recording",
    "write_set_recording",
]

PERIOD_NS = 33_333_333  # 30 fps
T0_NS = 5_000_000_000

# Fast supervision for tests: quick watchdog and reconnects, and frame-loss rates judged over
# 2 s (10 s by default) so the health is back to ok soon after a fault.
FAST_SUPERVISOR = SupervisorConfig(
    watchdog_s=0.3,
    reconnect_after_s=1.0,
    read_timeout_s=0.05,
    backoff_base_s=0.02,
    backoff_max_s=0.1,
    usb_reset_after=3,
    rate_window_s=2.0,
)
# For tests of something other than the cameras' health: on a busy machine (the suite's workers
# and a browser on two cores) a replay stalls for a moment, and a 0.3 s watchdog then marks the
# camera unavailable and depth answers 503 meanwhile.
CALM_SUPERVISOR = FAST_SUPERVISOR.model_copy(update={"watchdog_s": 5.0, "reconnect_after_s": 10.0})


def frame_image(cam: str, seq: int, width: int = 160, height: int = 120) -> NDArray[np.uint8]:
    """A textured image that differs per camera and frame (so byte comparisons mean something)."""
    rng = np.random.default_rng(seq * 2 + (cam == "right"))
    blocks = rng.integers(0, 256, (height // 8, width // 8, 3), dtype=np.uint8)
    img = np.asarray(cv2.resize(blocks, (width, height), interpolation=cv2.INTER_NEAREST), dtype=np.uint8)
    cv2.putText(img, f"{cam[0]}{seq}", (4, height // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2)
    return img


def encode(img: NDArray[Any], ext: str, quality: int | None = None) -> bytes:
    """``img`` as ``ext`` file bytes (JPEG at ``quality`` if given, else OpenCV's default)."""
    params = [] if quality is None else [cv2.IMWRITE_JPEG_QUALITY, quality]
    ok, buf = cv2.imencode(ext, img, params)
    assert ok
    return bytes(buf.tobytes())


def write_recording(
    root: Path,
    n: int = 30,
    *,
    ext: str = ".jpg",
    period_ns: int = PERIOD_NS,
    t0_ns: int = T0_NS,
    right_skew_ns: int = 0,
    seqs: Iterable[int] | None = None,
    width: int = 160,
    height: int = 120,
    calibration: str | None = None,
) -> Path:
    """A recording of ``n`` pairs on an exact timestamp grid (seq k at t0 + k·period)."""
    with RecordingWriter(root, meta={"source": "test"}) as w:
        for seq in seqs if seqs is not None else range(n):
            ts = t0_ns + seq * period_ns
            w.write_pair(
                seq,
                ts,
                ts + right_skew_ns,
                encode(frame_image("left", seq, width, height), ext),
                encode(frame_image("right", seq, width, height), ext),
                ext=ext,
            )
    if calibration is not None:
        (root / "calibration.yaml").write_text(calibration)
    return root


def write_set_recording(
    root: Path,
    cameras: tuple[str, ...],
    n: int = 10,
    *,
    skews_ns: tuple[int, ...] | None = None,
    ext: str = ".jpg",
    width: int = 160,
    height: int = 120,
) -> Path:
    """A recording of ``cameras`` (N of them), ``n`` sets on the exact grid of
    :func:`write_recording`, camera k ``skews_ns[k]`` after the first."""
    skews = skews_ns or (0,) * len(cameras)
    with RecordingWriter(root, meta={"source": "test"}, cameras=cameras) as w:
        for seq in range(n):
            ts = T0_NS + seq * PERIOD_NS
            frames = [encode(frame_image(c, seq, width, height), ext) for c in cameras]
            w.write_set(seq, [ts + s for s in skews], frames, ext=ext)
    return root


def replay_config(
    recording: Path,
    *,
    pace: str | float = 30.0,
    loop: bool = False,
    timestamps: str = "live",
    left_faults: tuple[dict[str, Any], ...] = (),
    right_faults: tuple[dict[str, Any], ...] = (),
    supervisor: SupervisorConfig = FAST_SUPERVISOR,
    pairing: PairingConfig | None = None,
) -> CaptureConfig:
    def cam(name: str, faults: tuple[dict[str, Any], ...]) -> dict[str, Any]:
        return {
            "kind": "file",
            "recording": str(recording),
            "camera": name,
            "pace": pace,
            "loop": loop,
            "timestamps": timestamps,
            "faults": list(faults),
        }

    doc: dict[str, Any] = {"left": cam("left", left_faults), "right": cam("right", right_faults)}
    cfg = CaptureConfig.model_validate(doc)
    return cfg.model_copy(update={"supervisor": supervisor, "pairing": pairing or PairingConfig()})


def file_camera_config(recording: Path, camera: str = "left", **kw: Any) -> FileCameraConfig:
    return FileCameraConfig.model_validate({"recording": str(recording), "camera": camera, **kw})


def jpeg_copy(source: Path, out: Path, quality: int = 90) -> Path:
    """``source`` (a rendered PNG recording) re-encoded as JPEG frames, same seqs and timestamps,
    with its calibration.yaml: what an MJPEG camera recording looks like."""
    src = Recording(source)
    with RecordingWriter(out, meta={"source": f"jpeg copy of {source}"}) as writer:
        for pair in src.pairs:
            left, right = (encode(src.read_image(pair, cam), ".jpg", quality) for cam in ("left", "right"))
            writer.write_pair(pair.seq, pair.left_ts_ns, pair.right_ts_ns, left, right, ext=".jpg")
    if src.calibration_path is not None:
        shutil.copyfile(src.calibration_path, out / "calibration.yaml")
    return out
