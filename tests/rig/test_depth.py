"""Disparity to depth, 16-bit PNG depth, point clouds and PLY files."""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.geometry import make_transform, rot_y
from calibration.models import LatLonModel, PinholeModel
from rig.depth import (
    depth_from_png_mm,
    depth_points,
    depth_to_png_mm,
    disparity_to_depth,
    latlon_range,
    read_ply,
    write_ply,
)
from rig.errors import PipelineError


def test_disparity_to_depth_closed_form_and_invalid() -> None:
    d = np.array([[10.0, 20.0, 0.0], [-3.0, np.nan, 0.5]], dtype=np.float32)
    z = disparity_to_depth(d, fx=320.0, baseline_m=0.072)
    assert z.dtype == np.float32
    assert z[0, 0] == pytest.approx(320 * 0.072 / 10) and z[0, 1] == pytest.approx(320 * 0.072 / 20)
    assert z[1, 2] == pytest.approx(320 * 0.072 / 0.5)
    assert np.isnan(z[0, 2]) and np.isnan(z[1, 0]) and np.isnan(z[1, 1])


def test_latlon_range_closed_form_and_invalid() -> None:
    """``B·(cos α·cot δ + sin α)`` in float64 where d > 0 and the triangle closes; NaN for NaN, 0
    and negative disparities, and for a ray pointing away from the baseline that would need the
    range to be negative. The NaNs do not change the other pixels' values."""
    cam = LatLonModel(5, 2, fx=1.5, fy=1.5, cx=2.0, cy=0.5)  # azimuths -76° to 76°, 38° apart
    az = cam.azimuths()
    d = np.array([[0.5, 0.3, 0.2, np.nan, 0.1], [0.0, -1.0, 0.2, 0.4, np.nan]], dtype=np.float32)
    r = latlon_range(d, cam, 0.072)
    delta = d.astype(np.float64) / cam.fx
    with np.errstate(divide="ignore", invalid="ignore"):
        expected = 0.072 * (np.cos(az) / np.tan(delta) + np.sin(az))
    ok = (d > 0) & (expected > 0)
    assert not ok[0, 0] and expected[0, 0] < 0  # at -76° a disparity of 0.5 closes no triangle
    assert np.array_equal(np.isfinite(r), ok)
    assert np.abs(r[ok] / expected[ok] - 1.0).max() < 1e-5  # float32 against float64
    # The same disparities without the NaNs: every other pixel bit for bit.
    clean = latlon_range(np.nan_to_num(d, nan=1.0), cam, 0.072)
    assert np.array_equal(clean[~np.isnan(d)], r[~np.isnan(d)], equal_nan=True)


def test_png_millimetres_round_trip_and_out_of_range(tmp_path: Path) -> None:
    depth = np.array([[0.2501, 1.0, 65.535], [65.6, np.nan, -1.0]], dtype=np.float32)
    mm = depth_to_png_mm(depth)
    assert mm.dtype == np.uint16
    assert mm.tolist() == [[250, 1000, 65535], [0, 0, 0]]  # too far to encode -> invalid, not clipped
    path = tmp_path / "d.png"
    assert cv2.imwrite(str(path), mm)
    back = np.asarray(cv2.imread(str(path), cv2.IMREAD_UNCHANGED))
    assert back.dtype == np.uint16 and np.array_equal(back, mm)
    m = depth_from_png_mm(back)
    assert m[0, 1] == pytest.approx(1.0) and np.isnan(m[1]).all()


def test_depth_points_lie_on_their_pixel_rays_in_the_rig_frame() -> None:
    cam = PinholeModel(8, 6, fx=4.0, fy=4.0, cx=3.5, cy=2.5)
    depth = np.full((6, 8), 2.0, dtype=np.float32)
    depth[0, 0] = np.nan
    depth[5, 7] = 3.0
    pts, idx = depth_points(depth, cam)
    assert pts.dtype == np.float32 and pts.shape == (47, 3) and idx.shape == (47,)
    assert 0 not in idx
    assert np.allclose(pts[:, 2], depth.reshape(-1)[idx])
    # Reprojecting each point gives its own pixel back.
    u, v = cam.fx * pts[:, 0] / pts[:, 2] + cam.cx, cam.fy * pts[:, 1] / pts[:, 2] + cam.cy
    assert np.allclose(u, idx % 8, atol=1e-5) and np.allclose(v, idx // 8, atol=1e-5)
    T = make_transform(rot_y(0.3), [1.0, -2.0, 0.5])
    pts_rig, _ = depth_points(depth, cam, T)
    assert np.allclose(pts_rig, pts @ T[:3, :3].T + T[:3, 3], atol=1e-5)
    sub, sub_idx = depth_points(depth, cam, stride=2)
    assert sub.shape[0] == 11 and set(sub_idx % 8) <= {0, 2, 4, 6} and set(sub_idx // 8) <= {0, 2, 4}
    with pytest.raises(PipelineError, match="stride"):
        depth_points(depth, cam, stride=0)


def test_ply_is_binary_little_endian_xyz_float32_with_optional_rgb(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(5, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, (5, 3)).astype(np.uint8)
    path = write_ply(tmp_path / "c.ply", pts, rgb)
    data = path.read_bytes()
    header, body = data.split(b"end_header\n", 1)
    assert header.decode().splitlines() == [
        "ply",
        "format binary_little_endian 1.0",
        "element vertex 5",
        "property float x",
        "property float y",
        "property float z",
        "property uchar red",
        "property uchar green",
        "property uchar blue",
    ]
    assert len(body) == 5 * 15
    # Parse independently of read_ply: 3 little-endian floats and 3 bytes per vertex.
    for i in range(5):
        x, y, z, r, g, b = struct.unpack_from("<fffBBB", body, 15 * i)
        assert (x, y, z) == tuple(float(c) for c in pts[i]) and (r, g, b) == tuple(int(c) for c in rgb[i])
    back, colours = read_ply(path)
    assert np.array_equal(back, pts) and colours is not None and np.array_equal(colours, rgb)
    plain = write_ply(tmp_path / "p.ply", pts)
    assert b"red" not in plain.read_bytes().split(b"end_header")[0]
    assert len(plain.read_bytes().split(b"end_header\n", 1)[1]) == 5 * 12
    back, colours = read_ply(plain)
    assert colours is None and np.array_equal(back, pts)
    empty = write_ply(tmp_path / "e.ply", np.zeros((0, 3)))
    assert read_ply(empty)[0].shape == (0, 3)
    with pytest.raises(PipelineError, match="colours"):
        write_ply(tmp_path / "bad.ply", pts, rgb[:4])
    (tmp_path / "x.ply").write_bytes(b"solid ascii stl")
    with pytest.raises(PipelineError, match="not a PLY"):
        read_ply(tmp_path / "x.ply")
