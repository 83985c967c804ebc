"""Frames as cameras deliver them: raw encoded bytes (MJPEG, PNG) plus a lazily decoded image.

A frame is decoded at most once per view: the first access to :attr:`Frame.gray` (the luma image
depth is computed from) or :attr:`Frame.image` (the full colour image, for clients asking for
it) decodes and caches, and a frame that cannot be decoded raises
:class:`~rig.errors.CorruptFrameError` every time it is asked (the supervisor counts those). So
does a frame whose header declares another size than the camera's (``expected_size``, or beyond
:data:`~rig.image_size.MAX_FRAME_SIDE` where the camera has none): read from the header before
decoding, so a small file declaring a huge image never allocates it.
:func:`encoded_problem` is the cheap structural check (markers only, no decode) used when
decoding in the capture thread is not wanted (recording).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from rig.errors import CorruptFrameError
from rig.image_size import size_problem

__all__ = [
    "FORMAT_EXTENSIONS",
    "Frame",
    "FrameFormat",
    "FramePair",
    "FrameSet",
    "encoded_problem",
    "format_of_path",
]

FrameFormat = Literal["jpeg", "png", "bgr"]
"""``jpeg`` / ``png``: ``raw`` holds the encoded bytes; ``bgr``: only a decoded image (YUYV cameras)."""

FORMAT_EXTENSIONS: dict[str, str] = {"jpeg": ".jpg", "png": ".png"}
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def format_of_path(name: str) -> FrameFormat:
    """Frame format from a recorded file name (``.jpg``/``.jpeg`` → jpeg, ``.png`` → png)."""
    lower = name.lower()
    if lower.endswith((".jpg", ".jpeg")):
        return "jpeg"
    if lower.endswith(".png"):
        return "png"
    raise CorruptFrameError(f"{name}: unsupported frame file type (expected .jpg or .png)")


def encoded_problem(data: bytes, fmt: FrameFormat) -> str | None:
    """What is structurally wrong with encoded frame bytes, or None when they look complete.

    JPEG: SOI marker, a marker right after it, EOI at the end (UVC cameras may pad with zero
    bytes after EOI, which is accepted). PNG: signature and a final IEND chunk. Catches the
    usual USB failures (truncated transfer, garbage header) without decoding.
    """
    if fmt == "jpeg":
        if len(data) < 4 or data[:2] != b"\xff\xd8":
            return "not a JPEG (no SOI marker)"
        if data[2] != 0xFF:
            return "JPEG header damaged (no marker after SOI)"
        if not data.rstrip(b"\x00").endswith(b"\xff\xd9"):
            return "JPEG truncated (no EOI marker at the end)"
        return None
    if fmt == "png":
        if not data.startswith(_PNG_SIGNATURE):
            return "not a PNG (bad signature)"
        if not data.endswith(_PNG_IEND):
            return "PNG truncated (no IEND chunk at the end)"
        return None
    return None


@dataclass(eq=False)
class Frame:
    """One frame from one camera.

    ``seq`` counts frames of that camera (gaps = frames the camera lost); ``ts_ns`` is the capture
    time (CLOCK_MONOTONIC ns for live cameras, the recorded value for verbatim replays);
    ``host_ns`` is when the frame reached this process (``time.monotonic_ns()``). ``raw`` holds
    the bytes exactly as delivered (MJPEG/PNG); ``source`` names where they came from, for
    error messages; ``expected_size`` is the camera's (width, height), which the raw bytes'
    header must declare to be decoded.
    """

    camera: str
    seq: int
    ts_ns: int
    format: FrameFormat
    host_ns: int
    raw: bytes | None = None
    source: str | None = None
    expected_size: tuple[int, int] | None = None
    _image: NDArray[Any] | None = field(default=None, repr=False)
    _gray: NDArray[np.uint8] | None = field(default=None, repr=False)
    _error: str | None = field(default=None, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def __post_init__(self) -> None:
        if self.raw is None and self._image is None:
            raise ValueError("a Frame needs raw bytes or an image")

    @classmethod
    def from_image(
        cls, camera: str, seq: int, ts_ns: int, image: NDArray[Any], host_ns: int, source: str | None = None
    ) -> Frame:
        """A frame the camera delivered already decoded (e.g. YUYV converted to BGR by OpenCV)."""
        return cls(camera, seq, ts_ns, "bgr", host_ns, None, source, _image=image)

    @property
    def extension(self) -> str | None:
        """File extension the raw bytes are stored under (``.jpg``/``.png``), None if no raw bytes."""
        return FORMAT_EXTENSIONS.get(self.format) if self.raw is not None else None

    def _describe(self) -> str:
        where = f" ({self.source})" if self.source else ""
        return f"camera {self.camera}: frame {self.seq}{where}"

    def check_structure(self) -> None:
        """Raise CorruptFrameError if the raw bytes are structurally broken (cheap, no decode)."""
        if self.raw is None:
            return
        problem = encoded_problem(self.raw, self.format)
        if problem:
            raise CorruptFrameError(f"{self._describe()}: {problem}")

    @property
    def image(self) -> NDArray[Any]:
        """The decoded image (H, W[, C]) as OpenCV returns it; decoded on first access, then cached."""
        with self._lock:
            if self._image is None:
                self._image = self._decode(cv2.IMREAD_UNCHANGED)
            return self._image

    @property
    def gray(self) -> NDArray[np.uint8]:
        """The luma image (H, W) uint8, what depth is computed from; decoded on first access,
        then cached.

        Encoded frames are decoded straight to gray: for JPEG that is the Y component as coded,
        and libjpeg skips the chroma upsampling and colour conversion (a 4:2:2 1280×960 MJPEG
        frame decodes in under half the time of its colour image). It does not depend on
        whether :attr:`image` was decoded first, so the depth of a frame never does either.
        Already decoded frames (``bgr``) are converted with OpenCV's BGR → gray."""
        with self._lock:
            if self._gray is None:
                if self.raw is None and self._image is not None:
                    img = self._image
                    self._gray = img if img.ndim == 2 else np.asarray(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
                else:
                    self._gray = self._decode(cv2.IMREAD_GRAYSCALE)
            return self._gray

    def _decode(self, flags: int) -> NDArray[Any]:
        """The raw bytes decoded with ``flags`` (under the lock); a failure is remembered."""
        if self._error is None:
            data = self.raw or b""
            fmt = self.format
            problem = encoded_problem(data, fmt) or size_problem(data, fmt, self.expected_size)
            img = None
            if problem is None:
                try:
                    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags)
                except cv2.error:
                    img = None
                problem = None if img is not None else f"{self.format} data does not decode"
            if img is not None:
                return np.asarray(img)
            self._error = problem
        raise CorruptFrameError(f"{self._describe()}: {self._error}")

    @property
    def decoded(self) -> bool:
        """Whether either view (:attr:`image` or :attr:`gray`) has been decoded."""
        return self._image is not None or self._gray is not None


@dataclass(frozen=True, eq=False)
class FrameSet:
    """One frame per camera, synchronised by nearest timestamps (:mod:`rig.capture.pairing`), in
    the capture's camera order. ``seq``/``ts_ns`` are the first camera's."""

    frames: tuple[Frame, ...]

    @property
    def cameras(self) -> list[str]:
        return [f.camera for f in self.frames]

    def frame(self, camera: str) -> Frame:
        for f in self.frames:
            if f.camera == camera:
                return f
        raise KeyError(f"no frame of camera {camera!r} in the set ({', '.join(self.cameras)})")

    @property
    def seq(self) -> int:
        return self.frames[0].seq

    @property
    def ts_ns(self) -> int:
        return self.frames[0].ts_ns

    @property
    def spread_ns(self) -> int:
        """Latest minus earliest capture time of the set (ns)."""
        stamps = [f.ts_ns for f in self.frames]
        return max(stamps) - min(stamps)


@dataclass(frozen=True, eq=False, init=False)
class FramePair(FrameSet):
    """Two frames paired by nearest timestamps: the set of a two-camera capture. ``seq``/``ts_ns``
    are the left frame's."""

    def __init__(self, left: Frame, right: Frame) -> None:
        object.__setattr__(self, "frames", (left, right))

    @property
    def left(self) -> Frame:
        return self.frames[0]

    @property
    def right(self) -> Frame:
        return self.frames[1]

    @property
    def skew_ns(self) -> int:
        """Left minus right capture time (ns)."""
        return self.left.ts_ns - self.right.ts_ns
