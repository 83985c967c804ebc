"""Every real calibration file in the shared data set loads, and agrees with independent
references (skipped cleanly, with the reason, when the data folder is absent)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from calibration import CalibrationFileError, detect_format, load_camera, load_rig
from calibration.geometry import invert_transform, make_transform, rotation_angle
from calibration.models import CameraModel
from tests.conftest import SHARED_DATA, shared_file

OPEN_VINS = "vio_fisheye_calibs/open_vins"
BASALT = "vio_fisheye_calibs/basalt"
# file -> (published stereo baseline in metres, tolerance)
KALIBR_FILES = {
    f"{OPEN_VINS}/tum_vi/kalibr_imucam_chain.yaml": (0.101, 0.002),
    f"{OPEN_VINS}/rs_t265/kalibr_imucam_chain.yaml": (0.0627, 0.001),
    f"{OPEN_VINS}/uzhfpv_indoor/kalibr_imucam_chain.yaml": (0.080, 0.002),
    f"{OPEN_VINS}/uzhfpv_outdoor/kalibr_imucam_chain.yaml": (0.080, 0.002),
}
BASALT_FILES = {
    f"{BASALT}/tumvi_512_ds_calib.json": (0.101, 0.002),
    f"{BASALT}/tumvi_512_eucm_calib.json": (0.101, 0.002),
    f"{BASALT}/euroc_ds_calib.json": (0.110, 0.002),
    f"{BASALT}/euroc_eucm_calib.json": (0.110, 0.002),
}
OCAMCALIB_FILES = [
    "ocamcalib_matsuren/calib_results_0.txt",
    "ocamcalib_vivekmudgal/calib_results.txt",
    "ocamcalib_premnirmal/calib_results.txt",
]
# The real files, also fed to the corruption fuzz test (skipped there when absent).
SHARED_SAMPLES = {rel: SHARED_DATA / rel for rel in [*KALIBR_FILES, *BASALT_FILES, *OCAMCALIB_FILES]}
# Present in the data set but not calibrations: corner lists, images, masks.
NOT_CALIBRATIONS = {
    "opencv_fisheye_calib3_stereo_JY/left.xml": "not a calibration file of a known format",
    "opencv_fisheye_calib3_stereo_JY/object.xml": "not a calibration file of a known format",
    "opencv_contrib_omnidir/omni_calib_data.xml": "not a calibration file of a known format",
    "opencv_contrib_omnidir/omni_stereocalib_data.xml": "not a calibration file of a known format",
    "ocamcalib_matsuren/img0.jpg": "binary content",
    f"{OPEN_VINS}/tum_vi/mask_tumvi0.png": "binary content",
}
BASALT_TYPES = {"ds": "double_sphere", "eucm": "eucm", "kb4": "kannala_brandt"}


def kalibr_yaml(path: Path) -> dict[str, Any]:
    """The file read without our loader: drop OpenCV's '%YAML:1.0' line, then plain PyYAML."""
    lines = path.read_text().splitlines()
    return yaml.safe_load("\n".join(line for line in lines if not line.startswith("%YAML")))


def relative(rig: Any) -> np.ndarray:
    return invert_transform(rig.T_rig_cam["right"]) @ rig.T_rig_cam["left"]


def pixel_grid(model: CameraModel, step: float = 8.0) -> np.ndarray:
    u, v = np.meshgrid(np.arange(0.0, model.width, step), np.arange(0.0, model.height, step))
    return np.stack([u.ravel(), v.ravel()], axis=1)


# ----- Kalibr (open_vins) --------------------------------------------------------------------------
@pytest.mark.parametrize("rel", KALIBR_FILES)
def test_kalibr_file_matches_cv2_fisheye_and_published_baseline(rel: str) -> None:
    path = shared_file(rel)
    assert detect_format(path) == "kalibr"
    raw = kalibr_yaml(path)
    rig = load_rig(path)
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(500, 3))
    pts[:, 2] = np.abs(pts[:, 2]) + 0.05  # in front: cv2.fisheye's domain
    for name, key in (("left", "cam0"), ("right", "cam1")):
        model = rig.cameras[name]
        fx, fy, cx, cy = raw[key]["intrinsics"]
        assert (model.width, model.height) == tuple(raw[key]["resolution"])
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        D = np.array(raw[key]["distortion_coeffs"], dtype=np.float64)
        ref, _ = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)
        px, ok = model.project(pts, in_image=False)
        assert ok.all()
        np.testing.assert_allclose(px, ref.reshape(-1, 2), rtol=1e-9, atol=1e-9)
    baseline, tol = KALIBR_FILES[rel]
    assert rig.baseline() == pytest.approx(baseline, abs=tol)
    if "T_cn_cnm1" in raw["cam1"]:
        np.testing.assert_allclose(relative(rig), np.array(raw["cam1"]["T_cn_cnm1"]), atol=1e-12)


# TUM VI's file has no T_cn_cnm1 (its pose comes from T_cam_imu alone); the others have both.
@pytest.mark.parametrize("rel", [r for r in KALIBR_FILES if "tum_vi" not in r])
def test_kalibr_chain_and_imu_extrinsics_agree(rel: str, tmp_path: Path) -> None:
    """Files with both T_cn_cnm1 and T_cam_imu: the rig built from either is the same."""
    path = shared_file(rel)
    raw = kalibr_yaml(path)
    del raw["cam1"]["T_cn_cnm1"]
    imu_only = tmp_path / "imu_only.yaml"
    imu_only.write_text(yaml.safe_dump(raw))
    a, b = load_rig(path), load_rig(imu_only)
    for name in ("left", "right"):
        np.testing.assert_allclose(a.T_rig_cam[name], b.T_rig_cam[name], atol=1e-9)


# ----- basalt ------------------------------------------------------------------------------------
@pytest.mark.parametrize("rel", BASALT_FILES)
def test_basalt_file_parameters_and_pose(rel: str) -> None:
    path = shared_file(rel)
    assert detect_format(path) == "basalt"
    raw = json.loads(path.read_text())["value0"]
    rig = load_rig(path)
    for i, name in enumerate(("left", "right")):
        model = rig.cameras[name]
        cam = raw["intrinsics"][i]
        assert model.name == BASALT_TYPES[cam["camera_type"]]
        assert model.param_dict == cam["intrinsics"]
        assert [model.width, model.height] == raw["resolution"][i]
        assert load_camera(path, f"cam{i}") == model
        # Every pixel of these lenses back-projects (the files describe the whole image).
        _, ok = model.unproject(pixel_grid(model))
        assert ok.mean() > 0.99
    T_imu = [
        make_transform(
            Rotation.from_quat([p["qx"], p["qy"], p["qz"], p["qw"]]).as_matrix(), [p["px"], p["py"], p["pz"]]
        )
        for p in raw["T_imu_cam"]
    ]
    np.testing.assert_allclose(relative(rig), invert_transform(T_imu[1]) @ T_imu[0], atol=1e-12)
    baseline, tol = BASALT_FILES[rel]
    assert rig.baseline() == pytest.approx(baseline, abs=tol)


@pytest.mark.parametrize("dataset", ["tumvi_512", "euroc"])
def test_double_sphere_and_eucm_files_describe_the_same_lenses(dataset: str) -> None:
    """Two parametrisations of one calibration: rays agree to 0.02° within 80° off axis."""
    ds, eucm = (
        shared_file(f"{BASALT}/{dataset}_ds_calib.json"),
        shared_file(f"{BASALT}/{dataset}_eucm_calib.json"),
    )
    for name in ("left", "right"):
        a, b = load_camera(ds, name), load_camera(eucm, name)
        ra, oa = a.unproject(pixel_grid(a))
        rb, ob = b.unproject(pixel_grid(a))
        ok = oa & ob & (ra[:, 2] > math.cos(math.radians(80.0)))
        angle = np.degrees(np.arccos(np.clip((ra * rb).sum(axis=1), -1.0, 1.0)))[ok]
        assert ok.sum() > 1000 and angle.max() < 0.02


def test_basalt_and_kalibr_tum_vi_calibrations_agree() -> None:
    """TUM VI calibrated by two tools (basalt DS, Kalibr KB4): same rig within 1 mm / 0.2°,
    same rays within 0.5° up to 80° off axis."""
    b = load_rig(shared_file(f"{BASALT}/tumvi_512_ds_calib.json"))
    k = load_rig(shared_file(f"{OPEN_VINS}/tum_vi/kalibr_imucam_chain.yaml"))
    Tb, Tk = relative(b), relative(k)
    assert np.linalg.norm(Tb[:3, 3] - Tk[:3, 3]) < 1e-3
    assert math.degrees(rotation_angle(Tb[:3, :3].T @ Tk[:3, :3])) < 0.2
    for name in ("left", "right"):
        grid = pixel_grid(b.cameras[name])
        rb, ob = b.cameras[name].unproject(grid)
        rk, ok_k = k.cameras[name].unproject(grid)
        ok = ob & ok_k & (rb[:, 2] > math.cos(math.radians(80.0)))
        angle = np.degrees(np.arccos(np.clip((rb * rk).sum(axis=1), -1.0, 1.0)))[ok]
        assert ok.sum() > 1000 and angle.max() < 0.5


# ----- OCamCalib ---------------------------------------------------------------------------------
def read_ocam(path: Path) -> dict[str, Any]:
    """The five numeric lines, as OCamCalib's own C reader (get_ocam_model) takes them."""
    rows = [
        [float(t) for t in line.split()]
        for line in path.read_text().splitlines()
        if line.strip() and not line.startswith("#")
    ]
    return {
        "pol": rows[0][1:],
        "invpol": rows[1][1:],
        "xc": rows[2][0],
        "yc": rows[2][1],
        "c": rows[3][0],
        "d": rows[3][1],
        "e": rows[3][2],
        "height": int(rows[4][0]),
        "width": int(rows[4][1]),
    }


def cam2world(m: dict[str, Any], row: float, col: float) -> tuple[float, float, float]:
    """OCamCalib ocam_functions.cpp cam2world, one point (point2D = (row, column))."""
    c, d, e = m["c"], m["d"], m["e"]
    invdet = 1.0 / (c - d * e)
    xp = invdet * ((row - m["xc"]) - d * (col - m["yc"]))
    yp = invdet * (-e * (row - m["xc"]) + c * (col - m["yc"]))
    r = math.sqrt(xp * xp + yp * yp)
    zp, r_i = m["pol"][0], 1.0
    for a in m["pol"][1:]:
        r_i *= r
        zp += r_i * a
    invnorm = 1.0 / math.sqrt(xp * xp + yp * yp + zp * zp)
    return invnorm * xp, invnorm * yp, invnorm * zp


def world2cam(m: dict[str, Any], X: float, Y: float, Z: float) -> tuple[float, float]:
    """OCamCalib ocam_functions.cpp world2cam, one point; returns (row, column)."""
    norm = math.sqrt(X * X + Y * Y)
    theta = math.atan(Z / norm)
    rho, t_i = m["invpol"][0], 1.0
    for b in m["invpol"][1:]:
        t_i *= theta
        rho += t_i * b
    x, y = X / norm * rho, Y / norm * rho
    return x * m["c"] + y * m["d"] + m["xc"], x * m["e"] + y + m["yc"]


@pytest.mark.parametrize("rel", OCAMCALIB_FILES)
def test_ocamcalib_file_matches_cam2world_and_world2cam(rel: str) -> None:
    path = shared_file(rel)
    assert detect_format(path) == "ocamcalib"
    m = read_ocam(path)
    model = load_camera(path)
    assert model.name == "scaramuzza" and (model.width, model.height) == (m["width"], m["height"])
    grid = pixel_grid(model, step=max(model.width, model.height) / 60.0)
    rays, ok = model.unproject(grid)
    assert ok.all()
    # OCamCalib frame (x = row, y = column, z backwards) -> ours (x = column, y = row, z forward).
    ref = np.array([cam2world(m, v, u) for u, v in grid])
    np.testing.assert_allclose(rays, np.stack([ref[:, 1], ref[:, 0], -ref[:, 2]], axis=1), atol=1e-12)

    # world2cam uses the file's fitted invpol: where that fit reproduces the file's own pol
    # (round trip under 0.02 px), our exact projection must land on the same pixel.
    px, okp = model.project(rays)
    assert okp.all()
    np.testing.assert_allclose(px, grid, atol=1e-6)
    w2c = np.array([world2cam(m, *r)[::-1] for r in ref])  # (column, row) = (u, v)
    good = np.linalg.norm(w2c - grid, axis=1) < 0.02
    assert good.mean() > 0.5
    assert np.abs(px - w2c)[good].max() < 0.025


# ----- not calibrations ----------------------------------------------------------------------------
@pytest.mark.parametrize("rel", NOT_CALIBRATIONS)
def test_other_shared_files_are_refused_clearly(rel: str) -> None:
    path = shared_file(rel)
    with pytest.raises(CalibrationFileError) as info:
        load_camera(path)
    assert str(info.value).startswith(f"{path}: {NOT_CALIBRATIONS[rel]}")
