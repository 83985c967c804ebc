"""VPC lookup tables: against OpenCV's fisheye maps, for every camera model, and their masks."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from calibration.geometry import rot_x, rot_y
from calibration.models import MODELS, KannalaBrandtModel, PinholeModel, create
from rig.errors import LutError
from rig.lut import INVALID_COORD, build_rectified_lut, percent_valid, rect_rays
from tests.calibration.model_cases import ModelCase, model_cases


def vpc(width: int, height: int, hfov_deg: float, cx_shift: float = 0.0) -> PinholeModel:
    f = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
    return PinholeModel(width, height, fx=f, fy=f, cx=(width - 1) / 2 + cx_shift, cy=(height - 1) / 2)


def kb190() -> KannalaBrandtModel:
    m = next(c.model for c in model_cases() if c.id == "kannala_brandt-190")
    assert isinstance(m, KannalaBrandtModel)
    return m


def opencv_maps(model: KannalaBrandtModel, R_cam_rect: np.ndarray, cam: PinholeModel) -> tuple:
    K = np.array([[model.fx, 0, model.cx], [0, model.fy, model.cy], [0, 0, 1]])
    D = np.array(model.k, dtype=np.float64)
    # OpenCV maps output pixel p to the fisheye ray R⁻¹·P⁻¹·p: its R is our R_cam_rect inverted.
    return cv2.fisheye.initUndistortRectifyMap(
        K, D, R_cam_rect.T, cam.K, (cam.width, cam.height), cv2.CV_32FC1
    )


def ray_angles(cam: PinholeModel, R: np.ndarray) -> np.ndarray:
    """Angle (H, W) of every VPC pixel's ray from the fisheye axis, computed independently."""
    v, u = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
    rays = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], axis=-1) @ R.T
    return np.arccos(rays[..., 2] / np.linalg.norm(rays, axis=-1))


@pytest.mark.parametrize(
    ("R", "hfov", "cx_shift"),
    [
        (np.eye(3), 90.0, 0.0),
        (rot_y(math.radians(-45)), 90.0, 0.0),
        (rot_y(math.radians(45)) @ rot_x(math.radians(10)), 110.0, 40.0),
        (rot_y(math.radians(60)) @ rot_x(math.radians(-5)), 120.0, 0.0),
    ],
    ids=["axis", "yaw-45", "yaw45-pitch10-shift", "yaw60-hfov120"],
)
def test_kb_lut_matches_opencv_where_opencv_is_valid(R: np.ndarray, hfov: float, cx_shift: float) -> None:
    model = kb190()
    cam = vpc(320, 240, hfov, cx_shift)
    lut = build_rectified_lut(model, R, cam)
    mx, my = opencv_maps(model, R, cam)
    theta = ray_angles(cam, R)
    inside = (mx >= -0.5) & (mx <= model.width - 0.5) & (my >= -0.5) & (my <= model.height - 0.5)
    cv_ok = np.isfinite(mx) & np.isfinite(my) & inside & (theta < math.radians(89.9))
    assert cv_ok.sum() > 1000
    # Everywhere OpenCV is valid, ours is valid and equal to 1e-3 px.
    assert lut.valid[cv_ok].all()
    err = np.hypot(lut.map_x[cv_ok] - mx[cv_ok], lut.map_y[cv_ok] - my[cv_ok])
    assert err.max() <= 1e-3, f"max deviation from OpenCV {err.max():.2e} px"


def test_kb_lut_stays_valid_beyond_90_degrees_where_opencv_is_not() -> None:
    model = kb190()  # 190° lens: sees up to 95° off axis
    R = rot_y(math.radians(60))
    cam = vpc(320, 240, 120.0)
    lut = build_rectified_lut(model, R, cam)
    mx, _ = opencv_maps(model, R, cam)
    theta = ray_angles(cam, R)
    beyond = (theta > math.radians(90.5)) & (theta < model.max_theta - 1e-3)
    assert beyond.sum() > 500
    assert lut.valid[beyond].all(), "our LUT must follow rays past 90° up to the lens limit"
    assert not np.isfinite(mx[beyond]).any(), "OpenCV gives no map there (the reason for our LUT)"
    # Past the lens limit nothing is valid; invalid entries point outside the image.
    past = theta > model.max_theta + 1e-6
    assert past.sum() > 100
    assert not lut.valid[past].any()
    assert (lut.map_x[~lut.valid] == INVALID_COORD).all() and (lut.map_y[~lut.valid] == INVALID_COORD).all()
    # Beyond-90° entries are right: unproject them (independent Newton inversion) back to the ray.
    v, u = np.nonzero(beyond)
    rays, ok = model.unproject(np.stack([lut.map_x[v, u], lut.map_y[v, u]], 1).astype(np.float64))
    assert ok.all()
    back = rays @ R  # fisheye frame -> VPC frame
    pu = cam.fx * back[:, 0] / back[:, 2] + cam.cx
    pv = cam.fy * back[:, 1] / back[:, 2] + cam.cy
    assert np.hypot(pu - u, pv - v).max() < 2e-3


def _lut_direction(case: ModelCase) -> tuple[np.ndarray, float]:
    """A VPC that straddles the lens's field limit for wide cases; on axis for narrow ones."""
    if case.wide:
        # Centre 20° inside the lens's limit, so the 110° VPC crosses it.
        yaw = min(math.degrees(case.model.max_theta) - 20.0, 80.0)
        return rot_y(math.radians(yaw)) @ rot_x(math.radians(8)), 110.0
    return rot_y(math.radians(12)), 70.0


@pytest.mark.parametrize("case", model_cases(), ids=lambda c: c.id)
def test_lut_round_trips_through_the_models_own_unprojection(case: ModelCase) -> None:
    model = case.model
    R, hfov = _lut_direction(case)
    cam = vpc(200, 150, hfov)
    lut = build_rectified_lut(model, R, cam)
    assert lut.map_x.dtype == np.float32 and lut.map_x.shape == (150, 200)
    assert lut.map1.dtype == np.int16 and lut.map1.shape == (150, 200, 2) and lut.map2.dtype == np.uint16
    assert lut.valid_fraction == pytest.approx(lut.valid.mean())
    v, u = np.nonzero(lut.valid)
    assert v.size > 0.2 * lut.valid.size
    pix = np.stack([lut.map_x[v, u], lut.map_y[v, u]], 1).astype(np.float64)
    assert model.in_image(pix).all()
    # (a) The sample positions' rays, projected in float64, land on the table's entries.
    rays_rect = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones(u.size)], 1)
    expected, ok = model.project(rays_rect @ R.T)
    assert ok.all()
    assert np.abs(expected - pix).max() < 1e-3
    # (b) Independently, the model's own unprojection of the entries returns the VPC pixel. Near a
    # lens's limit the fisheye compresses angles, so float32 entries (~1e-4 px) move the VPC
    # pixel by 1e-4 / σ_min(J), J = d(fisheye px)/d(VPC px): compare in fisheye pixels.
    rays, ok = model.unproject(pix)
    assert ok.mean() > 0.999
    back = rays @ R
    err = np.hypot(
        cam.fx * back[:, 0] / back[:, 2] + cam.cx - u, cam.fy * back[:, 1] / back[:, 2] + cam.cy - v
    )
    gx_u, gx_v = (
        np.gradient(lut.map_x.astype(np.float64), axis=1),
        np.gradient(lut.map_x.astype(np.float64), axis=0),
    )
    gy_u, gy_v = (
        np.gradient(lut.map_y.astype(np.float64), axis=1),
        np.gradient(lut.map_y.astype(np.float64), axis=0),
    )
    J = np.stack([np.stack([gx_u, gx_v], -1), np.stack([gy_u, gy_v], -1)], -2)[v, u]  # (N, 2, 2)
    sigma_min = np.linalg.svd(J, compute_uv=False)[:, -1]
    interior = cv2.erode(lut.valid.astype(np.uint8), np.ones((3, 3), np.uint8))[v, u].astype(bool)
    fisheye_err = (err * sigma_min)[interior & ok]
    assert fisheye_err.max() < 3e-4, f"round trip off by {fisheye_err.max():.2e} fisheye px"
    # Invalid where the lens cannot see: beyond its angular limit, or projecting off the image.
    theta = ray_angles(cam, R)
    assert not lut.valid[theta > model.max_theta * (1 + 1e-9)].any()


@pytest.mark.parametrize("case", model_cases(), ids=lambda c: c.id)
def test_lut_equals_the_models_project_on_every_pixel(case: ModelCase) -> None:
    """Block-wise building (and the rd = g(θ) fast path for equidistant/KB) changes nothing:
    same validity and positions as one ``model.project`` call on all VPC rays."""
    R, hfov = _lut_direction(case)
    cam = vpc(200, 150, hfov)
    lut = build_rectified_lut(case.model, R, cam)
    v, u = np.mgrid[0:150, 0:200].astype(np.float64)
    rays = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], -1).reshape(-1, 3)
    pix, ok = case.model.project(rays @ R.T)
    assert np.array_equal(lut.valid.ravel(), ok)
    assert np.abs(pix[ok] - np.stack([lut.map_x.ravel(), lut.map_y.ravel()], 1)[ok]).max() < 1e-3


@pytest.mark.parametrize("case", [c for c in model_cases() if c.wide], ids=lambda c: c.id)
def test_wide_lut_is_cut_by_the_lens_not_by_90_degrees(case: ModelCase) -> None:
    model = case.model
    R, hfov = _lut_direction(case)
    lut = build_rectified_lut(model, R, vpc(200, 150, hfov))
    theta = ray_angles(vpc(200, 150, hfov), R)
    assert 0.0 < lut.valid_fraction < 1.0, "this VPC should cross the lens's field limit"
    if model.max_theta > math.radians(91):
        assert lut.valid[theta > math.radians(90.5)].any()


def test_every_registered_model_has_a_lut_case() -> None:
    covered = {c.model.name for c in model_cases()}
    assert set(MODELS) <= covered, f"models without a LUT test case: {sorted(set(MODELS) - covered)}"


def test_vpc_that_sees_nothing_of_the_lens_is_an_error() -> None:
    with pytest.raises(LutError, match="sees nothing"):
        build_rectified_lut(kb190(), rot_y(math.pi), vpc(64, 48, 60.0))


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_bad_rotation_is_an_error() -> None:
    with pytest.raises(LutError, match="rotation"):
        build_rectified_lut(kb190(), np.diag([1.0, 1.0, -1.0]), vpc(64, 48, 60.0))
    with pytest.raises(LutError, match="rotation"):  # R·Rᵀ would overflow: refused before
        build_rectified_lut(kb190(), np.full((3, 3), 1e200), vpc(64, 48, 60.0))
    with pytest.raises(LutError, match="3x3"):
        rect_rays(vpc(64, 48, 60.0), np.eye(4))


def test_distorted_vpc_uses_its_unprojection() -> None:
    model = kb190()
    plain = vpc(120, 90, 80.0)
    distorted = PinholeModel(120, 90, fx=plain.fx, fy=plain.fy, cx=plain.cx, cy=plain.cy, k1=-0.05)
    a, b = build_rectified_lut(model, np.eye(3), plain), build_rectified_lut(model, np.eye(3), distorted)
    # Centre pixel unaffected by radial distortion; the corners move inwards (k1 < 0 barrel).
    assert abs(a.map_x[45, 60] - b.map_x[45, 60]) < 0.5
    assert np.hypot(b.map_x[0, 0] - model.cx, b.map_y[0, 0] - model.cy) > np.hypot(
        a.map_x[0, 0] - model.cx, a.map_y[0, 0] - model.cy
    )


def test_fixed_point_remap_matches_float_remap_and_blacks_out_invalid() -> None:
    model = create("equidistant", 400, 400, fx=127.0, fy=127.0, cx=199.5, cy=199.5, fov_deg=180.0)
    R = rot_y(math.radians(70))
    lut = build_rectified_lut(model, R, vpc(160, 120, 100.0))
    assert 0.0 < lut.valid_fraction < 1.0
    yy, xx = np.mgrid[0:400, 0:400]
    img = (128 + 100 * np.sin(xx / 9.0) * np.cos(yy / 7.0)).astype(np.uint8)
    fixed = lut.remap(img)
    ref = cv2.remap(
        img, lut.map_x, lut.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0
    )
    assert np.abs(fixed[lut.valid].astype(int) - ref[lut.valid].astype(int)).max() <= 1
    assert (fixed[~lut.valid] == 0).all()
    # Colour frames remap per channel with the same table.
    colour = lut.remap(np.dstack([img, img // 2, 255 - img]))
    assert colour.shape == (120, 160, 3) and (colour[~lut.valid] == 0).all()
    assert np.abs(colour[..., 0].astype(int) - fixed.astype(int)).max() == 0


@pytest.mark.parametrize(
    "fraction,text",
    [
        (1.0, "100.0%"),
        (0.99996, ">99.9%"),  # 12 of 307 200 pixels invalid: not "100.0%"
        (0.9995, ">99.9%"),
        (0.9994, "99.9%"),
        (0.5, "50.0%"),
        (0.0004, "<0.1%"),
        (0.0, "0.0%"),
    ],
)
def test_percent_valid_never_rounds_to_all_or_nothing(fraction: float, text: str) -> None:
    assert percent_valid(fraction) == text
