"""Encoders against independent computations, and the once-per-frame encode cache."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from rig.depth import depth_to_png16, read_ply
from service.client import parse_ply
from service.encoders import colorize_depth, disparity_to_png16, encode_png, ply_bytes
from service.store import EncodeCache, EncodeCounter


def test_depth_png16_mm_and_tenth_mm() -> None:
    depth = np.array([[0.5, 1.2344, np.nan], [-1.0, 70.0, 6.0]], dtype=np.float32)
    mm = depth_to_png16(depth, 0.001)
    # Independent: exact rounding of the float32 values, 0 for NaN, negative and > 65.535 m.
    assert mm.tolist() == [[500, 1234, 0], [0, 0, 6000]]
    tenth = depth_to_png16(depth, 0.0001)
    assert tenth[0, 0] == 5000 and tenth[1, 2] == 60000
    assert tenth[1, 1] == 0  # 70 m does not fit in 0.1 mm units: invalid, not saturated
    # PNG round trip keeps the 16-bit values exactly.
    back = cv2.imdecode(np.frombuffer(encode_png(tenth), np.uint8), cv2.IMREAD_UNCHANGED)
    assert back.dtype == np.uint16 and np.array_equal(back, tenth)


def test_png_is_lossless_at_every_compression_level() -> None:
    rng = np.random.default_rng(4)
    yy, xx = np.mgrid[0:120, 0:160]
    depth = (2000 + 900 * np.sin(xx / 20) + 300 * yy / 120 + rng.normal(0, 3, xx.shape)).astype(np.uint16)
    depth[rng.random(depth.shape) < 0.05] = 0
    sizes = {}
    for level in (0, 1, 6, 9):
        body = encode_png(depth, level)
        back = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_UNCHANGED)
        assert back.dtype == np.uint16 and np.array_equal(back, depth), level
        sizes[level] = len(body)
    assert sizes[0] > depth.nbytes  # stored: the raw rows plus PNG framing
    assert max(sizes[1], sizes[6], sizes[9]) < 0.7 * sizes[0]


def test_disparity_png16_sixteenth_pixels() -> None:
    disp = np.array([[1.0, 2.5625, np.nan, 0.0]], dtype=np.float32)
    assert disparity_to_png16(disp).tolist() == [[16, 41, 0, 0]]


def test_colorize_marks_invalid_black_and_orders_near_far() -> None:
    depth = np.array([[0.3, 1.0, 8.0, np.nan]], dtype=np.float32)
    img = colorize_depth(depth, 0.3, 8.0)
    assert img.shape == (1, 4, 3) and img.dtype == np.uint8
    assert img[0, 3].tolist() == [0, 0, 0]
    # Turbo: near end is red (R high, B low), far end blue-ish (B > R).
    assert img[0, 0, 2] > img[0, 0, 0]
    assert img[0, 2, 0] > img[0, 2, 2]
    lut = cv2.applyColorMap(np.array([[255, 0]], np.uint8), cv2.COLORMAP_TURBO)
    assert img[0, 0].tolist() == lut[0, 0].tolist() and img[0, 2].tolist() == lut[0, 1].tolist()


def test_ply_bytes_read_back_by_rig_depth_reader(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(50, 3)).astype(np.float32)
    cols = rng.integers(0, 256, (50, 3), dtype=np.uint8)
    data = ply_bytes(pts, cols)
    path = tmp_path / "cloud.ply"
    path.write_bytes(data)
    got_pts, got_cols = read_ply(path)  # the rig package's own reader, not ours
    assert np.array_equal(got_pts, pts) and got_cols is not None and np.array_equal(got_cols, cols)
    p2, c2 = parse_ply(data)
    assert np.array_equal(p2, pts) and c2 is not None and np.array_equal(c2, cols)


def test_encode_cache_encodes_once_under_concurrency() -> None:
    counter = EncodeCounter()
    cache = EncodeCache(counter)
    calls = 0
    lock = threading.Lock()

    def produce() -> bytes:
        nonlocal calls
        with lock:
            calls += 1
        time.sleep(0.05)  # long enough for every thread to arrive while the first encodes
        return b"encoded"

    results: list[bytes] = []
    threads = [
        threading.Thread(target=lambda: results.append(cache.get("depth_png", produce))) for _ in range(16)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert calls == 1
    assert results == [b"encoded"] * 16
    assert cache.peek("depth_png") == b"encoded"
    cache.get("pointcloud:2", lambda: b"p2")
    cache.get("pointcloud:4", lambda: b"p4")
    assert counter.snapshot() == {"depth_png": 1, "pointcloud": 2}


def test_encode_failure_is_not_cached() -> None:
    cache = EncodeCache()

    def boom() -> bytes:
        raise ValueError("x")

    with pytest.raises(ValueError):
        cache.get("k", boom)
    assert cache.peek("k") is None
    assert cache.get("k", lambda: b"ok") == b"ok"
