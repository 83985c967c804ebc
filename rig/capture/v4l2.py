"""UVC cameras through OpenCV's V4L2 backend (``cv2.VideoCapture(path, cv2.CAP_V4L2)``).

Negotiation sets FOURCC first (the V4L2 backend re-initialises the stream on a FOURCC change),
then size, fps and buffer count, then reads every value back: anything the camera did not
accept raises CameraFormatError naming what was asked and what was negotiated. For MJPG,
``CAP_PROP_CONVERT_RGB=0`` makes ``retrieve`` return the buffer's JPEG bytes untouched (1×N
uint8), so recordings are byte-exact and decoding happens once, later.

Timestamps: on the V4L2 backend ``CAP_PROP_POS_MSEC`` is the dequeued buffer's timestamp, which
uvcvideo takes from CLOCK_MONOTONIC (the clock of ``time.monotonic_ns()``). The first frame
after each open checks it: 0 (no buffer timestamps) or further than ``timestamp_tolerance_ms``
from the host clock selects the host-clock fallback, reported in ``info()`` and in health.

A stalled or unplugged camera blocks ``grab()`` for OpenCV's V4L2 select() timeout, 10 s by
default and not settable per capture (the V4L2 backend ignores ``CAP_PROP_READ_TIMEOUT_MSEC``);
it is read once per process from ``OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT`` (seconds), which this
module defaults to ``read_timeout_ms`` rounded up, before the first capture. The supervisor's
watchdog reports a stall long before that either way.

Controls use raw V4L2 units (OpenCV's default on V4L2): ``CAP_PROP_AUTO_EXPOSURE`` 1 = manual
(V4L2_EXPOSURE_MANUAL), 3 = aperture priority; ``CAP_PROP_EXPOSURE`` = exposure_time_absolute in
100 µs; ``CAP_PROP_AUTO_WB`` 0/1; ``CAP_PROP_WB_TEMPERATURE`` in kelvin.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, cast

import cv2

from rig.capture.config import V4L2CameraConfig
from rig.capture.frame import Frame
from rig.capture.protocol import CameraInfo, TimestampSource
from rig.errors import CameraFormatError, CameraUnavailable, CorruptFrameError

__all__ = ["V4L2Camera", "VideoCaptureLike", "fourcc_code", "fourcc_text", "resolve_device"]

V4L2_EXPOSURE_MANUAL = 1
# The controls read back after negotiation (rig check shows them): name → OpenCV property.
_READ_BACK = (
    ("auto_exposure", cv2.CAP_PROP_AUTO_EXPOSURE),
    ("exposure", cv2.CAP_PROP_EXPOSURE),
    ("gain", cv2.CAP_PROP_GAIN),
    ("auto_white_balance", cv2.CAP_PROP_AUTO_WB),
    ("white_balance", cv2.CAP_PROP_WB_TEMPERATURE),
)


class VideoCaptureLike(Protocol):
    """The part of ``cv2.VideoCapture`` this module uses (tests inject a stand-in)."""

    def isOpened(self) -> bool: ...
    def set(self, propId: int, value: float) -> bool: ...
    def get(self, propId: int) -> float: ...
    def grab(self) -> bool: ...
    def retrieve(self) -> tuple[bool, Any]: ...
    def release(self) -> None: ...


CaptureFactory = Callable[[str | int, int], VideoCaptureLike]


def fourcc_code(text: str) -> int:
    """FOURCC text (``"MJPG"``) → the integer OpenCV uses."""
    return int(cv2.VideoWriter.fourcc(*text))


def fourcc_text(code: float) -> str:
    """Integer FOURCC (as ``CAP_PROP_FOURCC`` returns it, a float) → text; ``"?"`` if unknown."""
    value = int(code)
    if value <= 0:
        return "?"
    return "".join(chr((value >> (8 * i)) & 0xFF) for i in range(4)).rstrip("\x00 ") or "?"


def resolve_device(device: str | int) -> str | int:
    """Index → int; path → the ``/dev/videoN`` it currently points to (by-path / udev links move
    to a new node after a re-plug, so this runs on every (re)open)."""
    if isinstance(device, int):
        return device
    if device.isdigit():
        return int(device)
    if not Path(device).exists():
        raise CameraUnavailable(f"{device}: no such device (unplugged? run `rig devices`)")
    return os.path.realpath(device)


def _close(got: float, want: float) -> bool:
    return abs(got - want) <= max(1.0, 0.01 * abs(want))


def _fmt(v: float) -> str:
    return f"{v:g}"


class V4L2Camera:
    """A UVC camera (see module docstring). ``capture_factory`` and ``usb_reset`` are the
    hardware seams: tests pass stand-ins, production uses ``cv2.VideoCapture`` and pyusb."""

    kind = "v4l2"

    def __init__(
        self,
        config: V4L2CameraConfig,
        name: str,
        *,
        capture_factory: CaptureFactory | None = None,
        usb_reset: Callable[[str], str] | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self.name = name
        self.config = config
        # Must be in the environment before OpenCV's first V4L2 select(); the user's value wins.
        os.environ.setdefault(
            "OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT", str(max(1, math.ceil(config.read_timeout_ms / 1000)))
        )
        self._factory: CaptureFactory = capture_factory or cast(CaptureFactory, cv2.VideoCapture)
        self._usb_reset = usb_reset
        self._clock = clock
        self._cap: VideoCaptureLike | None = None
        self._target: str | int | None = None
        self._negotiated: tuple[str, int, int, float] | None = None
        self._ts_source: TimestampSource | None = None
        self._ts_note: str | None = None
        self._seq = -1
        self._last_ts: int | None = None
        self._controls: dict[str, float] = {}

    # ----- protocol ----------------------------------------------------------------------------
    @property
    def nominal_fps(self) -> float:
        return self._negotiated[3] if self._negotiated else self.config.fps

    def info(self) -> CameraInfo:
        c = self.config
        fourcc, w, h, fps = self._negotiated or (c.fourcc, c.width, c.height, c.fps)
        target = f" → {self._target}" if self._target is not None and self._target != c.device else ""
        return CameraInfo(
            name=self.name,
            kind=self.kind,
            device=f"{c.device}{target}",
            format=fourcc,
            width=w,
            height=h,
            fps=fps,
            timestamp_source=self._ts_source,
            timestamp_note=self._ts_note,
        )

    def open(self) -> None:
        self.close()
        target = resolve_device(self.config.device)
        cap = self._factory(target, cv2.CAP_V4L2)
        if not cap.isOpened():
            cap.release()
            raise CameraUnavailable(
                f"camera {self.name}: cannot open {self.config.device} ({target}) with V4L2 "
                "(busy, unplugged, or no permission: is the user in group 'video'?)"
            )
        try:
            self._negotiate(cap, target)
        except BaseException:
            cap.release()
            raise
        self._cap, self._target = cap, target
        self._ts_source, self._ts_note, self._last_ts = None, None, None

    def close(self) -> None:
        cap, self._cap = self._cap, None
        if cap is not None:
            cap.release()

    def read(self, timeout_s: float) -> Frame | None:
        # One thread per camera: grab() dequeues the buffer (and stamps it), retrieve() copies it
        # out; OpenCV bounds the wait with CAP_PROP_READ_TIMEOUT_MSEC (set at open).
        cap = self._cap
        if cap is None:
            raise CameraUnavailable(f"camera {self.name}: not open")
        if not cap.grab():
            raise CameraUnavailable(f"camera {self.name}: {self.config.device} stopped delivering frames")
        host_ns = self._clock()
        ts_ns = self._timestamp(cap.get(cv2.CAP_PROP_POS_MSEC), host_ns)
        ok, data = cap.retrieve()
        seq = self._next_seq(ts_ns)
        if not ok or data is None or getattr(data, "size", 0) == 0:
            raise CorruptFrameError(f"camera {self.name}: frame {seq}: retrieve() returned no data")
        source = str(self._target)
        if self.config.fourcc == "MJPG" and data.ndim == 2 and data.shape[0] == 1:
            c = self.config
            size = self._negotiated[1:3] if self._negotiated else (c.width, c.height)
            return Frame(
                self.name, seq, ts_ns, "jpeg", host_ns, raw=data.tobytes(), source=source, expected_size=size
            )
        return Frame.from_image(self.name, seq, ts_ns, data, host_ns, source=source)

    def controls(self) -> dict[str, float]:
        """The exposure, gain and white-balance controls as the camera read them back at the last
        open (raw V4L2 units, see the module doc; empty before the first open)."""
        return dict(self._controls)

    def reset_hardware(self) -> str:
        if self._usb_reset is None:
            from rig.usb import reset_video_device  # pyusb only when a reset is really needed

            self._usb_reset = reset_video_device
        target = self._target
        if target is None:
            target = resolve_device(self.config.device)
        node = f"/dev/video{target}" if isinstance(target, int) else str(target)
        return self._usb_reset(node)

    # ----- negotiation -------------------------------------------------------------------------
    def _negotiate(self, cap: VideoCaptureLike, target: str | int) -> None:
        c = self.config
        refused: list[str] = []
        cap.set(cv2.CAP_PROP_FOURCC, fourcc_code(c.fourcc))
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, c.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, c.height)
        cap.set(cv2.CAP_PROP_FPS, c.fps)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, c.buffer_size)
        # Raw MJPEG bytes out of retrieve(); YUYV is converted to BGR by OpenCV.
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0 if c.fourcc == "MJPG" else 1)
        # Honoured by backends that support it; V4L2 uses OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT instead.
        cap.set(cv2.CAP_PROP_READ_TIMEOUT_MSEC, c.read_timeout_ms)

        fourcc = fourcc_text(cap.get(cv2.CAP_PROP_FOURCC))
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        fps = float(cap.get(cv2.CAP_PROP_FPS))
        if fourcc != c.fourcc:
            refused.append(f"format {c.fourcc} (gives {fourcc})")
        if (w, h) != (c.width, c.height):
            refused.append(f"size {c.width}x{c.height} (gives {w}x{h})")
        if abs(fps - c.fps) > c.fps_tolerance:
            refused.append(f"fps {_fmt(c.fps)} (gives {_fmt(fps)})")
        if int(cap.get(cv2.CAP_PROP_BUFFERSIZE)) != c.buffer_size:
            refused.append(f"buffer size {c.buffer_size} (gives {_fmt(cap.get(cv2.CAP_PROP_BUFFERSIZE))})")
        if c.fourcc == "MJPG" and cap.get(cv2.CAP_PROP_CONVERT_RGB) != 0:
            refused.append("raw MJPEG output (CONVERT_RGB=0)")
        controls: list[tuple[str, int, float]] = []
        if c.exposure is not None:
            controls += [
                ("manual exposure", cv2.CAP_PROP_AUTO_EXPOSURE, V4L2_EXPOSURE_MANUAL),
                ("exposure", cv2.CAP_PROP_EXPOSURE, c.exposure),
            ]
        if c.gain is not None:
            controls.append(("gain", cv2.CAP_PROP_GAIN, c.gain))
        if c.white_balance is not None:
            controls += [
                ("manual white balance", cv2.CAP_PROP_AUTO_WB, 0),
                ("white balance", cv2.CAP_PROP_WB_TEMPERATURE, c.white_balance),
            ]
        for label, prop, want in controls:
            accepted = cap.set(prop, want)
            got = cap.get(prop)
            if not accepted or not _close(got, want):
                refused.append(f"{label} {_fmt(want)} (gives {_fmt(got)})")
        self._controls = {name: float(cap.get(prop)) for name, prop in _READ_BACK}
        if refused:
            raise CameraFormatError(
                f"camera {self.name} ({target}) refused "
                + "; ".join(refused)
                + f"; negotiated {fourcc} {w}x{h} @ {_fmt(fps)} fps"
                + f" (list what it supports: v4l2-ctl -d {target} --list-formats-ext --list-ctrls)"
            )
        self._negotiated = (fourcc, w, h, fps)

    # ----- timestamps and sequence -------------------------------------------------------------
    def _timestamp(self, pos_msec: float, host_ns: int) -> int:
        buffer_ns = round(pos_msec * 1e6)
        if self._ts_source is None:
            offset_s = (buffer_ns - host_ns) / 1e9
            if pos_msec <= 0:
                self._ts_source = "host"
                self._ts_note = "CAP_PROP_POS_MSEC is 0: no V4L2 buffer timestamps, using the host clock"
            elif abs(offset_s) * 1e3 > self.config.timestamp_tolerance_ms:
                self._ts_source = "host"
                self._ts_note = (
                    f"V4L2 buffer timestamps are {offset_s:+.3f} s from CLOCK_MONOTONIC "
                    "(driver uses another clock), using the host clock"
                )
            else:
                self._ts_source = "v4l2"
        return buffer_ns if self._ts_source == "v4l2" else host_ns

    def _next_seq(self, ts_ns: int) -> int:
        # OpenCV hides the V4L2 sequence number; with buffer timestamps a gap of n periods means
        # n-1 frames lost in the driver. Host-clock timestamps are too jittery to infer that.
        step = 1
        if self._ts_source == "v4l2" and self._last_ts is not None and self._negotiated:
            period = 1e9 / self._negotiated[3] if self._negotiated[3] > 0 else 0
            if period > 0:
                step = max(1, round((ts_ns - self._last_ts) / period))
        self._last_ts = ts_ns
        self._seq += step
        return self._seq
