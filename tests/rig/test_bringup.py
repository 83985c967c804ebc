"""The bring-up check's V4L2 rows (exposure read back, USB bus budget) on the V4L2 camera code
with a stand-in for the driver and a fake sysfs tree (the file-camera rows: tests/cli/test_check.py;
a real camera: tests/rig/test_v4l2_device.py)."""

from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from rig.bringup import CheckRow, run_bringup
from rig.capture.config import CaptureConfig, V4L2CameraConfig
from rig.capture.v4l2 import V4L2Camera
from rig.rectified import RectifiedPairConfig
from tests.helpers.shots import prototype_rig
from tests.rig.test_capture_v4l2 import FakeHardware, FakeVideoCapture
from tests.rig.test_usb import machine

__all__ = ["machine"]


class PacedCapture(FakeVideoCapture):
    """The stand-in driver delivering at 30 fps instead of as fast as it is asked."""

    def grab(self) -> bool:
        time.sleep(1 / 30)
        return super().grab()


def cameras(hw: FakeHardware, config: CaptureConfig) -> dict[str, V4L2Camera]:
    def factory(target: str | int, api: int) -> Any:
        return PacedCapture(hw, target, api)

    return {n: V4L2Camera(config.camera(n), n, capture_factory=factory) for n in ("left", "right")}  # type: ignore[arg-type]


def rows_of(report: Any, check: str) -> dict[str, CheckRow]:
    return {r.camera: r for r in report.rows if r.check == check}


@pytest.mark.parametrize(
    ("fourcc", "size", "usb"), [("MJPG", (1280, 960), "pass"), ("YUYV", (800, 600), "fail")]
)
def test_exposure_read_back_and_the_usb_budget(
    machine: SimpleNamespace, tmp_path: Path, fourcc: str, size: tuple[int, int], usb: str
) -> None:
    hw = FakeHardware(formats={"MJPG": [(1280, 960)], "YUYV": [(800, 600)]})
    w, h = size
    common = {"fourcc": fourcc, "width": w, "height": h, "fps": 30.0}
    config = CaptureConfig(
        left=V4L2CameraConfig(device=0, exposure=100, **common),  # video0 and video2: both on bus 1
        right=V4L2CameraConfig(device=2, **common),
    )
    report = run_bringup(
        config,
        prototype_rig(1.0),
        vpc=RectifiedPairConfig(width=320, height=240),
        cache_dir=tmp_path,
        seconds=1.0,
        cameras=cameras(hw, config),
        sysfs_root=machine.sys,
    )
    exposure = rows_of(report, "exposure")
    assert exposure["left"].result == "pass" and "mode manual" in exposure["left"].value
    assert "exposure 100" in exposure["left"].value
    assert exposure["right"].result == "warn" and "cameras.left/right.exposure" in exposure["right"].action
    got = rows_of(report, "USB")
    assert {r.result for r in got.values()} == {usb}
    assert got["left"].value.startswith("bus 1 port 1-1.2, 480 Mb/s link")
    assert "with right" in got["left"].value
    if usb == "fail":
        assert "different root ports" in got["left"].action
    assert rows_of(report, "format")["left"].result == "pass"
