"""V4L2Camera logic against a stand-in for cv2.VideoCapture that behaves like a V4L2 driver:
it negotiates (keeps what it supports, falls back otherwise), stamps buffers, and unplugs."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from rig.capture.config import V4L2CameraConfig
from rig.capture.supervisor import CameraSupervisor
from rig.capture.v4l2 import V4L2Camera, fourcc_code, fourcc_text, resolve_device
from rig.errors import CameraFormatError, CameraUnavailable, CorruptFrameError
from tests.helpers.recordings import FAST_SUPERVISOR, encode, frame_image
from tests.helpers.waiting import wait_for

_CONTROLS = (cv2.CAP_PROP_AUTO_EXPOSURE, cv2.CAP_PROP_EXPOSURE, cv2.CAP_PROP_GAIN, cv2.CAP_PROP_AUTO_WB,
             cv2.CAP_PROP_WB_TEMPERATURE)  # fmt: skip


@dataclass
class FakeHardware:
    """What the simulated camera supports, and its state (shared by successive opens)."""

    formats: dict[str, list[tuple[int, int]]] = field(
        default_factory=lambda: {"MJPG": [(1280, 960), (640, 480)], "YUYV": [(640, 480)]}
    )
    rates: list[float] = field(default_factory=lambda: [30.0, 15.0])
    controls: dict[int, tuple[float, float]] = field(
        default_factory=lambda: {
            cv2.CAP_PROP_AUTO_EXPOSURE: (0, 3),
            cv2.CAP_PROP_EXPOSURE: (1, 5000),
            cv2.CAP_PROP_GAIN: (0, 255),
            cv2.CAP_PROP_AUTO_WB: (0, 1),
            cv2.CAP_PROP_WB_TEMPERATURE: (2800, 6500),
        }
    )
    present: bool = True
    pos_msec: Callable[[], float] = field(default_factory=lambda: lambda: time.monotonic_ns() / 1e6)
    # MJPEG frames of the size the default config negotiates (a frame of another size is refused).
    jpeg: bytes = field(default_factory=lambda: encode(frame_image("left", 0, 1280, 960), ".jpg"))
    opened_targets: list[Any] = field(default_factory=list)
    calls: list[tuple[str, int, float]] = field(default_factory=list)
    empty_retrieve: bool = False


class FakeVideoCapture:
    def __init__(self, hw: FakeHardware, target: str | int, api: int) -> None:
        assert api == cv2.CAP_V4L2
        hw.opened_targets.append(target)
        self.hw = hw
        self.opened = hw.present
        self.props: dict[int, float] = {
            cv2.CAP_PROP_FOURCC: fourcc_code("YUYV"),
            cv2.CAP_PROP_FRAME_WIDTH: 640,
            cv2.CAP_PROP_FRAME_HEIGHT: 480,
            cv2.CAP_PROP_FPS: 30.0,
            cv2.CAP_PROP_BUFFERSIZE: 4,
            cv2.CAP_PROP_CONVERT_RGB: 1,
            cv2.CAP_PROP_POS_MSEC: 0.0,
        }
        for prop, (lo, _) in hw.controls.items():
            self.props[prop] = lo
        self.grabbed = 0

    def isOpened(self) -> bool:
        return self.opened

    def set(self, prop: int, value: float) -> bool:
        self.hw.calls.append(("set", prop, value))
        if prop == cv2.CAP_PROP_FOURCC:
            if fourcc_text(value) in self.hw.formats:
                self.props[prop] = value
                return True
            return False
        if prop in (cv2.CAP_PROP_FRAME_WIDTH, cv2.CAP_PROP_FRAME_HEIGHT):
            self.props[prop] = value
            sizes = self.hw.formats[fourcc_text(self.props[cv2.CAP_PROP_FOURCC])]
            want = (self.props[cv2.CAP_PROP_FRAME_WIDTH], self.props[cv2.CAP_PROP_FRAME_HEIGHT])
            if want not in sizes:  # the driver picks its closest size
                w, h = min(sizes, key=lambda s: abs(s[0] - want[0]) + abs(s[1] - want[1]))
                self.props[cv2.CAP_PROP_FRAME_WIDTH], self.props[cv2.CAP_PROP_FRAME_HEIGHT] = w, h
            return True
        if prop == cv2.CAP_PROP_FPS:
            self.props[prop] = min(self.hw.rates, key=lambda r: abs(r - value))
            return True
        if prop == cv2.CAP_PROP_BUFFERSIZE:
            if 1 <= value <= 10:
                self.props[prop] = value
                return True
            return False
        if prop == cv2.CAP_PROP_CONVERT_RGB:
            self.props[prop] = value
            return True
        if prop in self.hw.controls:
            lo, hi = self.hw.controls[prop]
            self.props[prop] = min(max(value, lo), hi)
            return True
        return False  # e.g. CAP_PROP_READ_TIMEOUT_MSEC on an older build

    def get(self, prop: int) -> float:
        if prop in _CONTROLS and prop not in self.hw.controls:
            return -1.0
        return float(self.props.get(prop, -1.0))

    def grab(self) -> bool:
        if not self.hw.present:
            return False
        self.props[cv2.CAP_PROP_POS_MSEC] = self.hw.pos_msec()
        self.grabbed += 1
        return True

    def retrieve(self) -> tuple[bool, Any]:
        if self.hw.empty_retrieve:
            return False, None
        if (
            fourcc_text(self.props[cv2.CAP_PROP_FOURCC]) == "MJPG"
            and self.props[cv2.CAP_PROP_CONVERT_RGB] == 0
        ):
            return True, np.frombuffer(self.hw.jpeg, np.uint8).reshape(1, -1).copy()
        w, h = int(self.props[cv2.CAP_PROP_FRAME_WIDTH]), int(self.props[cv2.CAP_PROP_FRAME_HEIGHT])
        return True, np.zeros((h, w, 3), np.uint8)

    def release(self) -> None:
        self.opened = False


def make(hw: FakeHardware, resets: list[str] | None = None, **cfg: Any) -> V4L2Camera:
    config = V4L2CameraConfig.model_validate({"device": 3, **cfg})

    def usb_reset(node: str) -> str:
        assert resets is not None
        resets.append(node)
        return f"reset {node}"

    return V4L2Camera(
        config, "left", capture_factory=lambda t, api: FakeVideoCapture(hw, t, api), usb_reset=usb_reset
    )


def test_fourcc_round_trip_matches_opencv() -> None:
    assert fourcc_code("MJPG") == cv2.VideoWriter.fourcc(*"MJPG")
    assert fourcc_text(float(fourcc_code("YUYV"))) == "YUYV"
    assert fourcc_text(0) == "?"


def test_negotiation_sets_fourcc_first_and_reports_what_was_agreed() -> None:
    hw = FakeHardware()
    cam = make(hw, exposure=300, gain=20, white_balance=4600)
    cam.open()
    sets = [prop for kind, prop, _ in hw.calls if kind == "set"]
    assert sets.index(cv2.CAP_PROP_FOURCC) < sets.index(cv2.CAP_PROP_FRAME_WIDTH)
    # Manual exposure is selected before the exposure value; auto WB off before the temperature.
    assert sets.index(cv2.CAP_PROP_AUTO_EXPOSURE) < sets.index(cv2.CAP_PROP_EXPOSURE)
    assert sets.index(cv2.CAP_PROP_AUTO_WB) < sets.index(cv2.CAP_PROP_WB_TEMPERATURE)
    info = cam.info()
    assert (info.format, info.width, info.height, info.fps) == ("MJPG", 1280, 960, 30.0)
    assert hw.opened_targets == [3]


@pytest.mark.parametrize(
    "hw_kw,cfg,expected",
    [
        ({"formats": {"YUYV": [(640, 480)]}}, {}, "format MJPG (gives YUYV)"),
        ({"formats": {"MJPG": [(640, 480)]}}, {}, "size 1280x960 (gives 640x480)"),
        ({"rates": [15.0]}, {}, "fps 30 (gives 15)"),
        ({}, {"buffer_size": 10, "fps": 60}, "fps 60 (gives 30)"),
        ({"controls": {}}, {"exposure": 300}, "manual exposure 1 (gives -1); exposure 300 (gives -1)"),
        ({}, {"white_balance": 9000}, "white balance 9000 (gives 6500)"),
    ],
)
def test_refused_settings_raise_naming_what_was_refused(
    hw_kw: dict[str, Any], cfg: dict[str, Any], expected: str
) -> None:
    hw = FakeHardware(**hw_kw)
    cam = make(hw, **cfg)
    with pytest.raises(CameraFormatError, match="refused") as err:
        cam.open()
    msg = str(err.value)
    assert expected in msg and "camera left (3)" in msg and "v4l2-ctl -d 3" in msg


def test_unopenable_device() -> None:
    cam = make(FakeHardware(present=False))
    with pytest.raises(CameraUnavailable, match="group 'video'"):
        cam.open()


def test_device_links_are_resolved_again_on_every_open(tmp_path: Path) -> None:
    (tmp_path / "video0").touch()
    (tmp_path / "video2").touch()
    link = tmp_path / "by-path-usb-0:1.2:1.0-video-index0"
    link.symlink_to("video0")
    hw = FakeHardware()
    cam = make(hw, device=str(link))
    cam.open()
    link.unlink()
    link.symlink_to("video2")  # re-plugged: udev points the stable name at a new node
    cam.open()
    assert hw.opened_targets == [str(tmp_path / "video0"), str(tmp_path / "video2")]
    link.unlink()
    with pytest.raises(CameraUnavailable, match="no such device"):
        cam.open()
    assert resolve_device("4") == 4


def test_mjpeg_bytes_and_v4l2_timestamps() -> None:
    hw = FakeHardware()
    cam = make(hw)
    cam.open()
    f = cam.read(1.0)
    assert f is not None and f.raw == hw.jpeg and f.format == "jpeg"
    info = cam.info()
    assert info.timestamp_source == "v4l2" and info.host_clock and info.timestamp_note is None
    assert f.ts_ns == round(cam._cap.get(cv2.CAP_PROP_POS_MSEC) * 1e6)  # type: ignore[union-attr]
    assert f.ts_ns <= f.host_ns


@pytest.mark.parametrize(
    "pos,note",
    [
        (lambda: 0.0, "CAP_PROP_POS_MSEC is 0"),
        (lambda: time.time() * 1e3, "from CLOCK_MONOTONIC"),  # a driver stamping wall-clock time
    ],
)
def test_host_clock_fallback(pos: Callable[[], float], note: str) -> None:
    cam = make(FakeHardware(pos_msec=pos))
    cam.open()
    before = time.monotonic_ns()
    f = cam.read(1.0)
    after = time.monotonic_ns()
    info = cam.info()
    assert info.timestamp_source == "host" and note in (info.timestamp_note or "")
    assert f is not None and before <= f.ts_ns <= after  # host clock at grab time


def test_sequence_counts_frames_lost_in_the_driver() -> None:
    period_ms = 1000 / 30
    stamps = iter([1000.0, 1000.0 + period_ms, 1000.0 + 4 * period_ms, 1000.0 + 5 * period_ms])
    base = time.monotonic_ns() / 1e6 - 1000.0
    cam = make(FakeHardware(pos_msec=lambda: base + next(stamps)))
    cam.open()
    assert [cam.read(1.0).seq for _ in range(4)] == [0, 1, 4, 5]  # type: ignore[union-attr]


def test_unplug_and_empty_retrieve() -> None:
    hw = FakeHardware()
    cam = make(hw)
    cam.open()
    hw.empty_retrieve = True
    with pytest.raises(CorruptFrameError, match="no data"):
        cam.read(1.0)
    hw.present = False
    with pytest.raises(CameraUnavailable, match="stopped delivering"):
        cam.read(1.0)


def test_yuyv_frames_arrive_decoded() -> None:
    cam = make(FakeHardware(), fourcc="YUYV", width=640, height=480)
    cam.open()
    f = cam.read(1.0)
    assert f is not None and f.format == "bgr" and f.raw is None and f.image.shape == (480, 640, 3)


def test_reset_hardware_names_the_video_node() -> None:
    resets: list[str] = []
    cam = make(FakeHardware(), resets, device=7)
    assert cam.reset_hardware() == "reset /dev/video7"
    assert resets == ["/dev/video7"]


def test_supervisor_resets_usb_once_after_repeated_failures_then_recovers() -> None:
    hw = FakeHardware()
    resets: list[str] = []
    cam = make(hw, resets)
    sup = CameraSupervisor(cam, FAST_SUPERVISOR, lambda f: None)
    sup.start()
    try:
        wait_for(lambda: sup.state[0] == "available")
        hw.present = False  # unplugged: grab fails and so does every re-open
        wait_for(lambda: sup.counters["reconnect_attempts"] >= FAST_SUPERVISOR.usb_reset_after + 2)
        assert resets == ["/dev/video3"]  # once per outage, after usb_reset_after failures
        assert sup.counters["usb_resets"] == 1
        state, reason = sup.state
        assert state == "unavailable" and "cannot open" in (reason or "")
        hw.present = True
        wait_for(lambda: sup.state[0] == "available")
        assert sup.counters["reconnects"] == 1
    finally:
        sup.stop()


def test_real_opencv_reports_a_missing_device_clearly(tmp_path: Path) -> None:
    # The real cv2.VideoCapture on a path that is not a video device: one clear error.
    fake_node = tmp_path / "video99"
    fake_node.write_bytes(b"")
    cam = V4L2Camera(V4L2CameraConfig(device=os.fspath(fake_node)), "right")
    with pytest.raises(CameraUnavailable, match=r"camera right: cannot open"):
        cam.open()


def test_select_timeout_defaults_from_the_config(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT", raising=False)
    make(FakeHardware(), read_timeout_ms=2500)
    assert os.environ["OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT"] == "3"
    make(FakeHardware(), read_timeout_ms=100)  # the first value stays (OpenCV reads it once)
    assert os.environ["OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT"] == "3"
