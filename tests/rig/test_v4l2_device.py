"""The real V4L2 capture path against a real camera: opt-in, on the robot (docs/deployment.md,
"Bring-up check").

``RIG_TEST_V4L2_DEVICE=/dev/videoN`` runs one camera through ``V4L2Camera`` and its supervisor
(OpenCV's V4L2 backend, negotiation, buffer timestamps, read-back controls); two devices,
comma-separated (left first), also run the bring-up check of :mod:`rig.bringup` on them.
``RIG_TEST_V4L2_FORMAT`` picks the mode (default ``MJPG 640x480 30``). Without the variable every
test here skips, saying so.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np
import pytest

from rig.bringup import run_bringup
from rig.capture.config import CaptureConfig, SupervisorConfig, V4L2CameraConfig
from rig.capture.frame import Frame
from rig.capture.supervisor import CameraSupervisor
from rig.capture.v4l2 import V4L2Camera
from rig.sim import get_preset, scale_camera

DEVICE_ENV = "RIG_TEST_V4L2_DEVICE"
FORMAT_ENV = "RIG_TEST_V4L2_FORMAT"
DEVICES = [d.strip() for d in os.environ.get(DEVICE_ENV, "").split(",") if d.strip()]

pytestmark = pytest.mark.skipif(
    not DEVICES,
    reason=f"no real camera: set {DEVICE_ENV}=/dev/videoN (two, comma-separated, for the bring-up check) "
    "to run the real V4L2 capture path",
)


def camera_config(device: str) -> V4L2CameraConfig:
    fourcc, size, fps = os.environ.get(FORMAT_ENV, "MJPG 640x480 30").split()
    w, h = (int(v) for v in size.lower().split("x"))
    return V4L2CameraConfig(device=device, fourcc=fourcc, width=w, height=h, fps=float(fps))  # type: ignore[arg-type]


def test_the_device_exists() -> None:
    for device in DEVICES:
        assert Path(device).exists(), f"{DEVICE_ENV} names {device}, which does not exist (`rig devices`)"


def test_one_camera_through_the_real_capture_path() -> None:
    config = camera_config(DEVICES[0])
    camera = V4L2Camera(config, "left")
    frames: list[Frame] = []
    got = threading.Event()

    def sink(frame: Frame) -> None:
        frames.append(frame)
        if len(frames) >= 2 * config.fps:
            got.set()

    supervisor = CameraSupervisor(camera, SupervisorConfig(decode=True), sink)
    supervisor.start()
    try:
        assert got.wait(10.0), f"{len(frames)} frames in 10 s: {supervisor.health()}"
    finally:
        supervisor.stop()
    health = supervisor.health()
    info = camera.info()
    assert (info.format, info.width, info.height) == (config.fourcc, config.width, config.height)
    assert info.timestamp_source in ("v4l2", "host"), info
    ts = np.array([f.ts_ns for f in frames])
    assert (np.diff(ts) > 0).all(), "timestamps increase"
    period = float(np.median(np.diff(ts))) / 1e9
    if info.fps:
        assert period == pytest.approx(1.0 / info.fps, rel=0.25), "frames come at the negotiated rate"
    assert frames[-1].gray.shape == (config.height, config.width)
    assert health.counters["frames_corrupt"] == 0
    controls = camera.controls()
    assert set(controls) >= {"auto_exposure", "exposure", "gain"}, controls
    print(f"\n{info}\ncontrols read back: {controls}\nmedian frame period {period * 1e3:.1f} ms")


@pytest.mark.skipif(len(DEVICES) < 2, reason=f"the bring-up check needs two devices in {DEVICE_ENV}")
def test_the_bringup_check_on_two_cameras(tmp_path: Path) -> None:
    left, right = camera_config(DEVICES[0]), camera_config(DEVICES[1])
    # No calibration of these cameras here: the prototype's lenses at their size. The capture
    # checks are what this test is about; the calibration rows say what they measure.
    base = get_preset("prototype").rig
    rig = type(base)(
        {n: scale_camera(m, left.width / m.width) for n, m in base.cameras.items()}, base.T_rig_cam
    )
    report = run_bringup(CaptureConfig(left=left, right=right), rig, cache_dir=tmp_path, seconds=3.0)
    for row in report.rows:
        print(f"{row.check:15s} {row.camera:6s} {row.result:5s} {row.value} | {row.action}")
    capture = {"camera", "format", "frame rate", "timestamps", "pairing", "dropped", "corrupt", "USB"}
    failed = [r for r in report.rows if r.check in capture and r.result == "fail"]
    assert not failed, failed
