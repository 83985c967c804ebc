"""The level-1 PNG writer (SUB filter + ISA-L deflate) against OpenCV's decoder and against an
independent parse of the chunks, and the float → uint16 conversions against Python's round()."""

from __future__ import annotations

import math
import struct
import warnings
import zlib
from typing import Any

import cv2
import numpy as np
import pytest

from rig.depth import depth_to_png16
from service import encoders
from service.encoders import (
    DISPARITY_PNG_SCALE,
    depth_png,
    disparity_png,
    disparity_to_png16,
    encode_png,
)

SIGNATURE = b"\x89PNG\r\n\x1a\n"


def cv2_decode(body: bytes) -> np.ndarray:
    return np.asarray(cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_UNCHANGED))


def chunks(body: bytes) -> list[tuple[bytes, bytes]]:
    """(type, data) of every chunk, each CRC checked."""
    assert body[:8] == SIGNATURE
    out, pos = [], 8
    while pos < len(body):
        (length,) = struct.unpack(">I", body[pos : pos + 4])
        kind, data = body[pos + 4 : pos + 8], body[pos + 8 : pos + 8 + length]
        (crc,) = struct.unpack(">I", body[pos + 8 + length : pos + 12 + length])
        assert crc == zlib.crc32(kind + data), kind
        out.append((kind, data))
        pos += 12 + length
    assert pos == len(body)
    return out


def manual_decode(body: bytes) -> np.ndarray:
    """Greyscale PNG → (H, W) array with stdlib zlib and the PNG spec's SUB reconstruction
    written out per byte (Recon(x) = Filt(x) + Recon(x - bpp)), asserting every row is SUB."""
    parsed = chunks(body)
    assert [kind for kind, _ in parsed] == [b"IHDR", b"IDAT", b"IEND"]
    width, height, depth, colour, method, filt, interlace = struct.unpack(">IIBBBBB", parsed[0][1])
    assert (colour, method, filt, interlace) == (0, 0, 0, 0) and depth in (8, 16)
    assert parsed[2][1] == b""
    bpp = depth // 8
    stream = zlib.decompress(parsed[1][1])
    stride = 1 + width * bpp
    assert len(stream) == height * stride
    rows = []
    for y in range(height):
        line = stream[y * stride : (y + 1) * stride]
        assert line[0] == 1, f"row {y} has filter type {line[0]}, not SUB"
        recon = bytearray(line[1:])
        for x in range(bpp, len(recon)):
            recon[x] = (recon[x] + recon[x - bpp]) % 256
        rows.append(bytes(recon))
    return np.frombuffer(b"".join(rows), dtype=">u2" if bpp == 2 else np.uint8).reshape(height, width)


def random_u16(shape: tuple[int, int], seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 65536, shape, dtype=np.uint16)


def depth_like(shape: tuple[int, int] = (120, 161)) -> np.ndarray:
    """Float32 metres: a slanted wall with noise, NaN holes, a few too-far and negative pixels."""
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    depth = (1.5 + 0.8 * np.sin(xx / 17) + 0.4 * yy / shape[0] + rng.normal(0, 0.003, shape)).astype(
        np.float32
    )
    depth[rng.random(shape) < 0.2] = np.nan
    depth[rng.random(shape) < 0.01] = 80.0
    depth[rng.random(shape) < 0.01] = -1.0
    return depth


IMAGES = {
    "random 48x64": random_u16((48, 64), 1),
    "width 1": random_u16((37, 1), 2),
    "width 3": random_u16((5, 3), 3),
    "width 641": random_u16((7, 641), 4),
    "1x1": np.array([[0xBEEF]], np.uint16),
    "zeros": np.zeros((9, 10), np.uint16),
    "all 65535": np.full((9, 10), 65535, np.uint16),
    "depth mm": depth_to_png16(depth_like(), 0.001),
}


@pytest.mark.parametrize("name", list(IMAGES))
def test_level1_decodes_to_the_input(name: str) -> None:
    image = IMAGES[name]
    body = encode_png(image, 1)
    back = cv2_decode(body)
    assert back.dtype == np.uint16 and back.shape == image.shape and np.array_equal(back, image)
    # Independently: stdlib inflate + the spec's SUB reconstruction, big-endian samples. A filter
    # taken with bpp = 1 instead of 2, or little-endian samples, fails both decodes here for every
    # image but the all-zero one (and the all-65535 one for the byte order).
    assert np.array_equal(manual_decode(body).astype(np.uint16), image)


def test_level1_uint8_and_non_contiguous() -> None:
    gray = np.random.default_rng(5).integers(0, 256, (31, 47), dtype=np.uint8)
    for image in (gray, gray[:, ::2], random_u16((40, 30), 6)[::3, 1::2], random_u16((30, 40), 7).T):
        body = encode_png(image, 1)
        assert np.array_equal(manual_decode(body), image)
        back = cv2_decode(body)
        assert back.dtype == image.dtype and np.array_equal(back, image)


def test_level1_greyscale_skips_opencv_and_others_keep_it(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[Any, ...]] = []
    real = cv2.imencode

    def spy(*args: Any) -> Any:
        calls.append(args)
        return real(*args)

    monkeypatch.setattr(encoders.cv2, "imencode", spy)
    encode_png(random_u16((8, 9), 8), 1)
    assert calls == []
    bgr = np.random.default_rng(9).integers(0, 256, (8, 9, 3), dtype=np.uint8)
    assert np.array_equal(cv2_decode(encode_png(bgr, 1)), bgr)
    assert len(calls) == 1 and calls[0][2] == encoders._png_params(1)


@pytest.mark.parametrize("level", [0, 6])
def test_other_levels_still_opencv_and_lossless(level: int) -> None:
    image = depth_to_png16(depth_like(), 0.001)
    body = encode_png(image, level)
    kinds = [kind for kind, _ in chunks(body)]  # CRCs checked
    assert kinds[0] == b"IHDR" and kinds[-1] == b"IEND" and b"IDAT" in kinds
    back = cv2_decode(body)
    assert back.dtype == np.uint16 and np.array_equal(back, image)


def test_depth_and_disparity_png_round_trip() -> None:
    depth = depth_like()
    for body, units in (
        (depth_png(depth, 0.001), depth_to_png16(depth, 0.001)),
        (depth_png(depth, 0.0001), depth_to_png16(depth, 0.0001)),
        (disparity_png(np.float32(40.0) / depth), disparity_to_png16(np.float32(40.0) / depth)),
    ):
        assert np.array_equal(cv2_decode(body), units)
        assert np.array_equal(manual_decode(body), units)
    units = depth_to_png16(depth, 0.001)
    assert 0 < np.count_nonzero(units == 0) < units.size  # the holes really are there


def reference_units(values: np.ndarray, scale: float) -> list[int]:
    """Python's round() (half to even) of each value / scale in float64, 0 outside 1…65535."""
    out = []
    for v in values.ravel().tolist():
        u = v / scale
        r = round(u) if math.isfinite(u) else 0
        out.append(r if 1 <= r <= 65535 else 0)
    return out


def edge_values(scale: float) -> np.ndarray:
    """Float32 values at, and 1 ulp either side of, unit ties and of the 16-bit range's ends."""
    k = np.array([0, 1, 2, 3, 1000, 1234, 65533, 65534, 65535, 65536, 70000], np.float64)
    centres = np.concatenate([k * scale, (k + 0.5) * scale, (k - 0.5) * scale]).astype(np.float32)
    up = np.nextafter(centres, np.float32(np.inf))
    down = np.nextafter(centres, np.float32(-np.inf))
    special = np.array([np.nan, np.inf, -np.inf, -0.0, -1.0, 1e-45, 3.4028235e38, -3.4028235e38], np.float32)
    return np.concatenate([centres, up, down, special])


@pytest.mark.parametrize("scale", [0.001, 0.0001, 0.01, 1 / 3])
def test_depth_to_png16_matches_python_rounding(scale: float) -> None:
    values = edge_values(scale)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = depth_to_png16(values, scale)
    assert got.dtype == np.uint16 and got.tolist() == reference_units(values, scale)


def test_disparity_to_png16_matches_python_rounding() -> None:
    values = edge_values(DISPARITY_PNG_SCALE)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # float32 overflow to inf stays quiet
        got = disparity_to_png16(values)
        got64 = disparity_to_png16(values.astype(np.float64))
    expected = reference_units(values, DISPARITY_PNG_SCALE)
    assert got.dtype == np.uint16 and got.tolist() == expected and got64.tolist() == expected
    # Ties to even at the top: 65534.5 → 65534, 65535.5 → 65536, beyond the range.
    assert disparity_to_png16(np.array([65534.5, 65535.5], np.float32) / 16).tolist() == [65534, 0]
