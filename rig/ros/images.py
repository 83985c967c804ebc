"""numpy images ↔ ROS ``sensor_msgs/msg/Image`` encodings (the names of ``sensor_msgs``'
``image_encodings``), and which message a recorded or live frame becomes.

Frames the camera delivered as JPEG travel as ``CompressedImage`` (format ``jpeg``, the bytes
untouched); PNG frames and frames that arrived decoded travel as raw images (``mono8``,
``bgr8``, ``mono16``…), the pixels exactly.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["RawPixels", "decode_raw_image", "raw_pixels"]

_TO_BGR = {"rgb8": cv2.COLOR_RGB2BGR, "rgba8": cv2.COLOR_RGBA2BGR, "bgra8": cv2.COLOR_BGRA2BGR}
_YUV = {"uyvy": cv2.COLOR_YUV2BGR_UYVY, "yuv422": cv2.COLOR_YUV2BGR_UYVY, "yuyv": cv2.COLOR_YUV2BGR_YUY2}
_YUV["yuv422_yuy2"] = cv2.COLOR_YUV2BGR_YUY2
# encoding → (dtype, channels)
_LAYOUT: dict[str, tuple[str, int]] = {
    "mono8": ("u1", 1),
    "8UC1": ("u1", 1),
    "bgr8": ("u1", 3),
    "8UC3": ("u1", 3),
    "rgb8": ("u1", 3),
    "bgra8": ("u1", 4),
    "rgba8": ("u1", 4),
    "mono16": ("u2", 1),
    "16UC1": ("u2", 1),
    "32FC1": ("f4", 1),
}


@dataclass(frozen=True)
class RawPixels:
    """An image as ``sensor_msgs/msg/Image`` holds it: little-endian rows of ``step`` bytes."""

    encoding: str
    width: int
    height: int
    step: int
    data: bytes


def raw_pixels(image: NDArray[Any], *, depth_mm: bool = False) -> RawPixels:
    """``image`` as a ROS raw image: uint8 gray ``mono8``, BGR ``bgr8``, BGRA ``bgra8``, uint16
    ``mono16`` (``16UC1`` with ``depth_mm``: REP 118's millimetre depth), float32 ``32FC1``."""
    a = np.ascontiguousarray(image)
    h, w = a.shape[:2]
    channels = 1 if a.ndim == 2 else a.shape[2]
    if a.dtype == np.uint8 and channels in (1, 3, 4):
        encoding = {1: "mono8", 3: "bgr8", 4: "bgra8"}[channels]
    elif a.dtype == np.uint16 and channels == 1:
        encoding = "16UC1" if depth_mm else "mono16"
    elif a.dtype == np.float32 and channels == 1:
        encoding = "32FC1"
    else:
        raise ValueError(f"no ROS image encoding for a {a.dtype} image of shape {a.shape}")
    data = a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()
    return RawPixels(encoding, w, h, w * channels * a.dtype.itemsize, data)


def decode_raw_image(
    encoding: str, width: int, height: int, step: int, data: bytes | NDArray[Any], bigendian: bool = False
) -> NDArray[Any]:
    """A ROS raw image as the pipeline takes frames: uint8/uint16 gray (H, W) or BGR (H, W, 3).
    ValueError for encodings it does not read (Bayer, floats for frames...)."""
    buf = data.view(np.uint8).reshape(-1) if isinstance(data, np.ndarray) else np.frombuffer(data, np.uint8)
    if encoding in _YUV:
        rows = _rows(buf, height, step, width * 2)
        return np.asarray(cv2.cvtColor(rows.reshape(height, width, 2), _YUV[encoding]))
    if encoding not in _LAYOUT:
        raise ValueError(f"image encoding {encoding!r} is not read (use mono8, bgr8, rgb8, mono16 or yuv422)")
    kind, channels = _LAYOUT[encoding]
    dtype = np.dtype(kind).newbyteorder(">" if bigendian else "<")
    rows = _rows(buf, height, step, width * channels * dtype.itemsize)
    img = rows.view(dtype).reshape((height, width) if channels == 1 else (height, width, channels))
    img = img.astype(dtype.newbyteorder("="), copy=False)
    if encoding in _TO_BGR:
        return np.asarray(cv2.cvtColor(img, _TO_BGR[encoding]))
    return np.ascontiguousarray(img)


def _rows(buf: NDArray[np.uint8], height: int, step: int, row_bytes: int) -> NDArray[np.uint8]:
    if step < row_bytes or buf.size < step * (height - 1) + row_bytes or height <= 0:
        raise ValueError(
            f"image data of {buf.size} bytes does not hold {height} rows of {row_bytes} bytes (step {step})"
        )
    if buf.size < step * height:  # the last row's padding may be missing
        buf = np.concatenate([buf, np.zeros(step * height - buf.size, np.uint8)])
    return np.ascontiguousarray(buf[: step * height].reshape(height, step)[:, :row_bytes])
