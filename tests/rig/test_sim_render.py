"""The renderer against closed-form geometry: analytic plane depth, feature positions at
``camera.project`` of known 3D points (also > 90° off axis), the lens circle, anti-aliasing,
vignetting, noise, and chessboard corners found by OpenCV where they should be."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from calibration.geometry import make_transform, rot_x, rot_y, rot_z, transform_points
from calibration.models import CameraModel, PinholeModel, create
from rig.errors import SimulationError
from rig.sim import (
    ImageTexture,
    Scene,
    TexturedRect,
    chessboard_corners,
    chessboard_scene,
    get_preset,
    plane_scene,
    render,
    room_scene,
)
from rig.sim.rays import camera_rays


def pinhole(w: int = 160, h: int = 120, f: float = 100.0) -> PinholeModel:
    return PinholeModel(w, h, fx=f, fy=f * 1.01, cx=(w - 1) / 2 + 3.2, cy=(h - 1) / 2 - 2.1)


def equidistant180(size: int = 200) -> CameraModel:
    f = size / math.pi
    return create("equidistant", size, size, fx=f, fy=f, cx=(size - 1) / 2, cy=(size - 1) / 2, fov_deg=180.0)


def kb190(scale: float = 0.5) -> CameraModel:
    return get_preset("prototype").scaled(scale).rig.cameras["left"]


def pixel_grid(cam: CameraModel) -> np.ndarray:
    u, v = np.meshgrid(np.arange(cam.width, dtype=float), np.arange(cam.height, dtype=float))
    return np.stack([u.ravel(), v.ravel()], axis=1)


def test_pinhole_depth_equals_analytic_plane() -> None:
    cam = pinhole()
    T = make_transform(rot_y(0.2) @ rot_x(-0.1) @ rot_z(0.05), [0.1, -0.05, 0.2])
    d = 2.0
    out = render(plane_scene(d, "noise", size_m=40.0, texture_px=256), cam, T, supersample=1)
    # Independent rays: K^-1 [u, v, 1] (z = 1), not the model's unproject.
    pix = pixel_grid(cam)
    ray_c = np.stack(
        [(pix[:, 0] - cam.cx) / cam.fx, (pix[:, 1] - cam.cy) / cam.fy, np.ones(len(pix))], axis=1
    )
    ray_w = ray_c @ T[:3, :3].T
    t = (d - T[2, 3]) / ray_w[:, 2]  # z = d plane in the world
    np.testing.assert_allclose(out.depth.ravel(), t, rtol=2e-7)
    np.testing.assert_allclose(out.distance.ravel(), t * np.linalg.norm(ray_c, axis=1), rtol=2e-7)
    assert out.valid.all() and out.depth.dtype == np.float32 and out.image.dtype == np.uint8


def test_fisheye_depth_equals_analytic_plane_past_90_degrees() -> None:
    cam = kb190(0.25)
    # Camera looking sideways (+x): the plane z = 1.5 is seen up to ~95° off axis.
    T = make_transform(rot_y(math.radians(80)), [0.0, 0.0, 0.0])
    d = 1.5
    out = render(plane_scene(d, "blobs", size_m=200.0, texture_px=256), cam, T, supersample=1)
    rays, ok = cam.unproject(pixel_grid(cam))
    ray_w = rays @ T[:3, :3].T
    with np.errstate(divide="ignore"):
        t = np.where(ray_w[:, 2] > 0, d / ray_w[:, 2], np.nan)
    t[~ok] = np.nan
    # Beyond the 200 m plane's edge nothing is hit.
    p = ray_w * t[:, None]
    t[(np.abs(p[:, 0]) > 100) | (np.abs(p[:, 1]) > 100)] = np.nan
    np.testing.assert_array_equal(np.isnan(out.distance.ravel()), np.isnan(t))
    np.testing.assert_allclose(out.distance.ravel(), t, rtol=2e-7)
    np.testing.assert_allclose(out.depth.ravel(), t * rays[:, 2], rtol=2e-6, atol=1e-6)
    assert (rays[ok & np.isfinite(t), 2] < -0.05).any(), "some hits should lie > 93° off axis"


def _dot_scene(point: np.ndarray, eye: np.ndarray, sigma_px: float, cam_f: float) -> Scene:
    """A dark square centred on ``point`` facing ``eye``, with a gaussian dot at its centre
    about ``sigma_px`` wide in an image of focal length ``cam_f``."""
    dist = float(np.linalg.norm(point - eye))
    sigma_m = sigma_px * dist / cam_f
    size = 14 * sigma_m
    n = 64
    yy, xx = np.mgrid[0:n, 0:n] + 0.5
    blob = 255.0 * np.exp(-((xx - n / 2) ** 2 + (yy - n / 2) ** 2) / (2 * (sigma_m * n / size) ** 2))
    z = (point - eye) / dist  # the square's normal looks back at the camera
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    T = make_transform(np.column_stack([x, np.cross(z, x), z]), point)
    return Scene(
        [TexturedRect(T, (size, size), ImageTexture(blob.astype(np.float32), (size, size), repeat=False))]
    )


def _centroid(img: np.ndarray, near: np.ndarray, half: int = 9) -> np.ndarray:
    u0, v0 = np.round(near).astype(int)
    win = img[v0 - half : v0 + half + 1, u0 - half : u0 + half + 1].astype(np.float64)
    vv, uu = np.mgrid[v0 - half : v0 + half + 1, u0 - half : u0 + half + 1]
    return np.array([(win * uu).sum() / win.sum(), (win * vv).sum() / win.sum()])


@pytest.mark.parametrize(
    ("name", "make", "angles_deg"),
    [
        ("pinhole", lambda: pinhole(320, 240, 200.0), [(0.0, 0.0), (25.0, -15.0), (-30.0, 20.0)]),
        ("equidistant", lambda: equidistant180(300), [(10.0, 5.0), (60.0, 0.0), (-50.0, 45.0)]),
        ("kannala_brandt", lambda: kb190(0.5), [(0.0, 0.0), (70.0, 10.0), (93.0, 0.0), (-93.0, 0.0)]),
    ],
)
def test_dot_lands_at_projection_of_its_3d_point(
    name: str, make: object, angles_deg: list[tuple[float, float]]
) -> None:
    """A dot's image centroid is off its centre's projection by c·σ² (the lens is not linear
    across the dot); two dot sizes extrapolate that away (Richardson) to a point-size dot."""
    cam: CameraModel = make()  # type: ignore[operator]
    T_world_cam = make_transform(rot_y(0.3) @ rot_x(0.1), [0.5, -0.2, 1.0])
    eye = T_world_cam[:3, 3]
    f = float(cam.param_dict["fx"])
    s_big, s_small = 1.6, 1.0
    for yaw, pitch in angles_deg:
        # 1.3 m away, yaw/pitch off the camera's optical axis.
        p_cam = 1.3 * (rot_y(math.radians(yaw)) @ rot_x(math.radians(pitch)) @ np.array([0.0, 0.0, 1.0]))
        p_world = transform_points(T_world_cam, p_cam[None])[0]
        expected, ok = cam.project(p_cam[None])
        assert ok[0], (name, yaw, pitch)
        # Render a 32x32 crop around the dot: the same model with the principal point moved.
        corner = np.round(expected[0]).astype(int) - 16
        crop = cam.replace(
            width=32, height=32, cx=cam.param_dict["cx"] - corner[0], cy=cam.param_dict["cy"] - corner[1]
        )
        errs = []
        for sigma in (s_big, s_small):
            out = render(_dot_scene(p_world, eye, sigma, f), crop, T_world_cam, supersample=4)
            errs.append(_centroid(out.image, expected[0] - corner) - (expected[0] - corner))
        point_err = (s_big**2 * errs[1] - s_small**2 * errs[0]) / (s_big**2 - s_small**2)
        where = f"{name} at ({yaw}°, {pitch}°): errors {errs[0]}, {errs[1]} -> {point_err}"
        assert np.linalg.norm(errs[1]) < 0.08, where
        assert np.linalg.norm(point_err) < 0.03, where


def test_fast_rays_equal_unproject() -> None:
    for cam in (kb190(0.5), equidistant180(256), get_preset("prototype").rig.cameras["right"]):
        rng = np.random.default_rng(0)
        pix = np.column_stack([rng.uniform(-1, cam.width, 50_000), rng.uniform(-1, cam.height, 50_000)])
        rays, ok = camera_rays(cam, pix)
        ref, ref_ok = cam.unproject(pix)
        np.testing.assert_array_equal(ok, ref_ok)
        assert ok.mean() > 0.3
        np.testing.assert_allclose(rays[ok], ref[ok], atol=1e-12)


def test_fisheye_valid_mask_is_the_lens_circle() -> None:
    cam = equidistant180(120)
    out = render(room_scene(0), cam, np.eye(4), supersample=2, background=77)
    pix = pixel_grid(cam)
    r = np.hypot(pix[:, 0] - 59.5, pix[:, 1] - 59.5) / (120 / math.pi)  # = θ for an equidistant lens
    expected = (r <= math.pi / 2).reshape(out.valid.shape)
    np.testing.assert_array_equal(out.valid, expected)
    assert (out.image[~expected] == 77).all()
    # The room encloses the camera: every ray the lens sees hits a wall.
    assert np.isfinite(out.depth[expected]).all() and np.isnan(out.depth[~expected]).all()
    assert (out.image[expected] != 77).mean() > 0.9


def test_kb190_valid_mask_is_a_clipped_circle() -> None:
    cam = kb190(0.25)
    p = cam.param_dict
    out = render(room_scene(1), cam, np.eye(4), supersample=1)
    pix = pixel_grid(cam)
    # θd at 95° from Table II's polynomial, written out independently of the model.
    th = math.radians(95.0)
    k = [p["k1"], p["k2"], p["k3"], p["k4"]]
    rd95 = th * (1 + k[0] * th**2 + k[1] * th**4 + k[2] * th**6 + k[3] * th**8)
    rd = np.hypot((pix[:, 0] - p["cx"]) / p["fx"], (pix[:, 1] - p["cy"]) / p["fy"])
    expected = (rd <= rd95).reshape(out.valid.shape)
    near_edge = (np.abs(rd - rd95) < 1e-9).reshape(out.valid.shape)
    np.testing.assert_array_equal(out.valid[~near_edge], expected[~near_edge])
    assert expected[0].any() and not expected[:, 0].any(), "circle cut at the top, inside left/right"
    assert (out.image[~out.valid] == 0).all() and np.isfinite(out.depth[out.valid]).all()


def test_supersampling_antialiases_an_edge() -> None:
    cam = create("pinhole", 48, 32, fx=50.0, fy=50.0, cx=23.5, cy=15.5)
    edge_u = 20.25
    x0 = (edge_u - 23.5) / 50.0  # world x of the edge on the z = 1 plane
    white = ImageTexture(np.full((2, 2), 255.0, np.float32), (1.0, 1.0))
    scene = Scene([TexturedRect(make_transform(np.eye(3), [x0 + 5.0, 0.0, 1.0]), (10.0, 10.0), white)])
    sharp = render(scene, cam, np.eye(4), supersample=1).image
    assert set(np.unique(sharp)) == {0, 255}
    smooth = render(scene, cam, np.eye(4), supersample=4).image
    # Column 20 spans u in [19.5, 20.5]; a quarter of it lies right of the edge.
    np.testing.assert_array_equal(smooth[:, 20], round(255 * 0.25))
    assert (smooth[:, :20] == 0).all() and (smooth[:, 21:] == 255).all()


def test_vignetting_follows_its_formula_and_noise_is_seeded() -> None:
    cam = pinhole(160, 120, 60.0)
    grey = ImageTexture(np.full((2, 2), 200.0, np.float32), (1.0, 1.0))
    scene = Scene([TexturedRect(make_transform(np.eye(3), [0, 0, 2.0]), (100.0, 100.0), grey)])
    flat = render(scene, cam, np.eye(4), supersample=1).image
    assert (flat == 200).all()
    vig = render(scene, cam, np.eye(4), supersample=1, vignetting=0.6).image.astype(float)
    pix = pixel_grid(cam)
    ray = np.stack([(pix[:, 0] - cam.cx) / cam.fx, (pix[:, 1] - cam.cy) / cam.fy, np.ones(len(pix))], axis=1)
    cos_t = 1.0 / np.linalg.norm(ray, axis=1)
    expected = 200.0 * (1 - 0.6 * (1 - ((1 + cos_t) / 2) ** 2))
    np.testing.assert_allclose(vig.ravel(), expected, atol=0.5 + 1e-6)
    assert vig.min() < 170
    a = render(scene, cam, np.eye(4), supersample=1, noise_std=4.0, seed=3).image.astype(float)
    b = render(scene, cam, np.eye(4), supersample=1, noise_std=4.0, seed=3).image.astype(float)
    c = render(scene, cam, np.eye(4), supersample=1, noise_std=4.0, seed=4).image.astype(float)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert abs((a - 200).std() - 4.0) < 0.3 and abs((a - 200).mean()) < 0.2


def test_color_render_agrees_with_grey_and_tiling_changes_nothing() -> None:
    cam = equidistant180(96)
    scene = room_scene(2)
    grey = render(scene, cam, np.eye(4), supersample=2)
    color = render(scene, cam, np.eye(4), supersample=2, color=True)
    assert color.image.shape == (96, 96, 3) and grey.image.shape == (96, 96)
    diff = np.abs(cv2.cvtColor(color.image, cv2.COLOR_BGR2GRAY).astype(int) - grey.image)
    assert diff.max() <= 2
    # 3-pixel tiles (tight cones, few candidate rectangles) and one tile (every rectangle).
    for tile_px in (3, 96):
        other = render(scene, cam, np.eye(4), supersample=2, tile_px=tile_px)
        np.testing.assert_array_equal(other.image, grey.image)
        np.testing.assert_array_equal(other.depth, grey.depth)


def test_chessboard_corners_found_where_and_in_the_order_promised() -> None:
    cam = create("pinhole", 640, 480, fx=500.0, fy=500.0, cx=319.5, cy=239.5)
    for roll in (0.0, -0.3):
        T_board = make_transform(rot_y(0.3) @ rot_x(-0.2) @ rot_z(roll), [-0.15, -0.1, 0.9])
        out = render(chessboard_scene(9, 6, 0.04, T_board), cam, np.eye(4), background=128)
        ok, corners = cv2.findChessboardCornersSB(
            out.image, (9, 6), cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
        )
        assert ok
        expected, _ = cam.project(transform_points(T_board, chessboard_corners(9, 6, 0.04)))
        # Same order (a reversed or shifted order would be off by a square, 20+ px).
        assert np.linalg.norm(corners.reshape(-1, 2) - expected, axis=1).max() < 0.5
        # Refined, OpenCV's detector is ~0.06 px RMS even on an ideal box-filtered board.
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-5)
        refined = cv2.cornerSubPix(out.image, corners, (5, 5), (-1, -1), criteria).reshape(-1, 2)
        err = np.linalg.norm(refined - expected, axis=1)
        assert err.max() < 0.25 and np.sqrt((err**2).mean()) < 0.1, (roll, err.max())


def test_chessboard_corners_layout() -> None:
    c = chessboard_corners(3, 2, 0.5)
    np.testing.assert_array_equal(
        c, [[0, 0, 0], [0.5, 0, 0], [1.0, 0, 0], [0, 0.5, 0], [0.5, 0.5, 0], [1.0, 0.5, 0]]
    )


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_render_rejects_bad_arguments() -> None:
    cam = pinhole()
    scene = plane_scene(1.0, texture_px=64)
    for kwargs in (
        {"supersample": 0},
        {"supersample": 2.5},
        {"noise_std": -1.0},
        {"vignetting": 1.5},
        {"background": 300},
    ):
        with pytest.raises(SimulationError):
            render(scene, cam, np.eye(4), **kwargs)
    with pytest.raises(SimulationError, match="4x4"):
        render(scene, cam, np.eye(3))
    with pytest.raises(SimulationError, match="rigid"):
        render(scene, cam, np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(SimulationError, match="rigid"):
        render(scene, cam, np.diag([1e200, 1e200, 1e200, 1.0]))
    with pytest.raises(SimulationError, match="rigid"):
        TexturedRect(np.diag([1e200, 1.0, 1.0, 1.0]), (1.0, 1.0), scene.rects[0].texture, "huge")
    with pytest.raises(SimulationError):
        plane_scene(-1.0)
    with pytest.raises(SimulationError):
        chessboard_scene(1, 5, 0.1, np.eye(4))
