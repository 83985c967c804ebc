"""Range from disparity for both rectified projections, against closed-form triangulation of the
two pixels' rays (the least-squares closest points of two lines, no law of sines), and point
clouds from range."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from calibration.geometry import make_transform, rot_y
from calibration.models import CameraModel, LatLonModel, PinholeModel, create
from rig.depth import (
    depth_points,
    depth_to_range,
    disparity_to_depth,
    disparity_to_range,
    latlon_range,
    pixel_ray_norms,
    range_points,
)
from rig.errors import PipelineError

F64 = NDArray[np.float64]
B = 0.072
LATLON = LatLonModel(200, 300, fx=150.0, fy=140.0, cx=110.3, cy=160.0)  # ±40° az, ±60° el
PINHOLE = PinholeModel(200, 150, fx=100.0, fy=101.0, cx=95.5, cy=80.0)


def _triangulate(left_rays: F64, right_rays: F64) -> F64:
    """Range along each left ray of the point closest to both lines (left centre at 0, right
    centre at (B, 0, 0)): solve ``t·l − s·r = c`` in the least-squares sense."""
    c = np.array([B, 0.0, 0.0])
    out = np.empty(left_rays.shape[0])
    for i, (lr, rr) in enumerate(zip(left_rays, right_rays, strict=True)):
        A = np.stack([lr, -rr], axis=1)
        (t, _), *_ = np.linalg.lstsq(A, c, rcond=None)
        out[i] = t * np.linalg.norm(lr)
    return out


def _disparities(camera: CameraModel, ranges: F64) -> tuple[F64, F64, F64]:
    """For every pixel of ``camera`` a point at ``ranges`` (H, W) along its ray: the disparity
    ``u_left − u_right`` of its projections, and both views' rays through those pixels."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    px = np.stack([u.ravel(), v.ravel()], axis=1)
    rays, ok = camera.unproject(px)
    assert ok.all()
    pts = rays * ranges.reshape(-1, 1)
    right_px, ok = camera.project(pts - [B, 0.0, 0.0], in_image=False)
    assert ok.all()
    assert np.abs(right_px[:, 1] - px[:, 1]).max() < 1e-9, "rows are epipolar planes"
    right_rays, _ = camera.unproject(right_px, in_image=False)
    return (px[:, 0] - right_px[:, 0]).reshape(ranges.shape), rays, right_rays


@pytest.mark.parametrize("camera", [LATLON, PINHOLE], ids=["latlon", "pinhole"])
def test_range_from_disparity_equals_ray_triangulation(camera: CameraModel) -> None:
    rng = np.random.default_rng(1)
    ranges = rng.uniform(0.15, 30.0, (camera.height, camera.width))
    d, left, right = _disparities(camera, ranges)
    assert (d > 0).all()
    got = disparity_to_range(d.astype(np.float32), camera, B)
    assert got.dtype == np.float32
    sel = rng.choice(d.size, 400, replace=False)
    reference = _triangulate(left[sel], right[sel])
    assert np.allclose(reference, ranges.reshape(-1)[sel], rtol=1e-9)  # the reference itself
    # float32 disparities: ~1e-7 relative, times the ~1/δ conditioning of far points.
    rel = np.abs(got.reshape(-1)[sel] / reference - 1.0)
    assert rel.max() < 2e-4, f"{rel.max():.2e}"
    rel_all = np.abs(got / ranges - 1.0)
    assert np.median(rel_all) < 1e-5


def test_pinhole_range_is_depth_times_ray_length() -> None:
    rng = np.random.default_rng(2)
    d = rng.uniform(0.5, 60.0, (PINHOLE.height, PINHOLE.width)).astype(np.float32)
    depth = disparity_to_depth(d, PINHOLE.fx, B)
    rng_m = depth_to_range(depth, PINHOLE)
    pts, idx = depth_points(depth, PINHOLE)
    assert np.allclose(np.linalg.norm(pts, axis=1), rng_m.reshape(-1)[idx], rtol=1e-6)
    # Rows from the middle of the image with their rows of ray norms: the whole image's numbers.
    norms = pixel_ray_norms(PINHOLE)
    assert np.array_equal(depth_to_range(depth[40:60], PINHOLE, norms[40:60]), rng_m[40:60])
    assert np.array_equal(disparity_to_range(d[40:60], PINHOLE, B, ray_norms=norms[40:60]), rng_m[40:60])
    with pytest.raises(PipelineError, match="range: depth is 200x20"):
        depth_to_range(depth[40:60], PINHOLE)


def test_invalid_disparities_give_no_range() -> None:
    d = np.array([[np.nan, 0.0, -2.0, -0.0, 1e-44, 3.0]], dtype=np.float32)
    cam = LatLonModel(6, 1, fx=100.0, fy=100.0, cx=2.5, cy=0.0)
    r = latlon_range(d, cam, B)
    assert np.isnan(r[0, :5]).all() and np.isfinite(r[0, 5]) and r[0, 5] > 0
    # A disparity past the triangle: the right ray would look back past the baseline (α_R < −90°).
    edge = LatLonModel(3, 1, fx=100.0, fy=100.0, cx=2.0 + 100.0 * 1.4, cy=0.0)  # α ≈ −80°
    assert np.isnan(latlon_range(np.full((1, 3), 30.0, np.float32), edge, B)).all()
    with pytest.raises(PipelineError, match="no disparity-to-range"):
        disparity_to_range(d, create("equidistant", 6, 1, fx=1.0, fy=1.0, cx=0.0, cy=0.0), B)


@pytest.mark.parametrize("camera", [LATLON, PINHOLE], ids=["latlon", "pinhole"])
def test_range_points_lie_on_their_pixel_rays_in_the_rig_frame(camera: CameraModel) -> None:
    rng = np.random.default_rng(3)
    r = rng.uniform(0.5, 5.0, (camera.height, camera.width)).astype(np.float32)
    r[0, 0] = np.nan
    r[1, 1] = -1.0
    pts, idx = range_points(r, camera)
    assert pts.shape == (r.size - 2, 3) and 0 not in idx and camera.width + 1 not in idx
    assert np.allclose(np.linalg.norm(pts, axis=1), r.reshape(-1)[idx], rtol=1e-6)
    back, ok = camera.project(pts.astype(np.float64))
    assert ok.all()
    assert np.allclose(back[:, 0], idx % camera.width, atol=1e-3)
    assert np.allclose(back[:, 1], idx // camera.width, atol=1e-3)
    T = make_transform(rot_y(0.4), [0.1, 0.2, -0.3])
    in_rig, _ = range_points(r, camera, T, stride=3)
    sub, sub_idx = range_points(r, camera, stride=3)
    assert np.allclose(in_rig, sub @ T[:3, :3].T + T[:3, 3], atol=1e-5)
    assert set(sub_idx % camera.width) <= set(range(0, camera.width, 3))
    if isinstance(camera, PinholeModel):  # the pinhole's depth-based cloud is the same cloud
        v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
        length = np.sqrt(1 + ((u - camera.cx) / camera.fx) ** 2 + ((v - camera.cy) / camera.fy) ** 2)
        depth = np.where(r > 0, r / length, np.nan).astype(np.float32)
        z_pts, z_idx = depth_points(depth, camera)
        assert np.array_equal(z_idx, idx) and np.allclose(z_pts, pts, atol=1e-5)


def test_law_of_sines_example_by_hand() -> None:
    """One triangle worked by hand: α = 30°, δ = 2° → range = B·cos 28° / sin 2°."""
    fx = 180.0 / math.pi  # 1 px per degree
    cam = LatLonModel(61, 1, fx=fx, fy=fx, cx=30.0, cy=0.0)  # column 60 looks 30° right
    d = np.zeros((1, 61), np.float32)
    d[0, 60] = 2.0
    r = latlon_range(d, cam, B)
    assert r[0, 60] == pytest.approx(B * math.cos(math.radians(28.0)) / math.sin(math.radians(2.0)), rel=1e-6)
