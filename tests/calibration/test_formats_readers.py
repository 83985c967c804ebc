"""Each reader on files written the way their own tools write them, checked against independent
references: cv2 projections, per-point formulas transcribed from the tools, scipy rotations."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration import CalibrationFileError, detect_format, load_camera, load_rig
from calibration.geometry import invert_transform, make_transform
from tests.calibration.test_formats_samples import (
    CAMODOCAL_KB,
    CAMODOCAL_MEI,
    CAMODOCAL_PINHOLE,
    CAMODOCAL_SCARAMUZZA,
    FRONT,
    OCAM_INVPOL,
    OCAM_POLY,
    OCAMCALIB_TEXT,
    T_C1_C0,
    TUM_D,
    TUM_K,
    K_of,
    basalt_doc,
    cata_space_to_plane,
    fisheye_reference,
    kalibr_doc,
    ocam_lift,
    ocam_space_to_plane,
    opencv_fisheye_entries,
    pinhole_reference,
    relative,
    write_filestorage,
    write_yaml,
)


# ----- Kalibr ------------------------------------------------------------------------------------
@pytest.mark.parametrize("opencv_header", [False, True])
def test_kalibr_cameras_match_opencv(tmp_path: Path, opencv_header: bool) -> None:
    path = write_yaml(tmp_path / "camchain.yaml", kalibr_doc(), opencv_header)
    assert detect_format(path) == "kalibr"
    left = load_camera(path, "cam0")
    assert left.name == "kannala_brandt" and left == load_camera(path, "left") == load_camera(path)
    px, ok = left.project(FRONT, in_image=False)
    ref = fisheye_reference(K_of(left), TUM_D, FRONT)
    assert ok.all()
    np.testing.assert_allclose(px, ref, rtol=1e-9, atol=1e-9)

    right = load_camera(path, "cam1")
    doc = kalibr_doc()["cam1"]
    assert right.name == "pinhole" and (right.width, right.height) == (752, 480)
    front = FRONT[FRONT[:, 2] > 2.0 * np.linalg.norm(FRONT[:, :2], axis=1)]  # radtan is valid near the axis
    px, ok = right.project(front, in_image=False)
    assert ok.all() and len(front) > 20
    np.testing.assert_allclose(px, pinhole_reference(K_of(right), doc["distortion_coeffs"], front), atol=1e-8)


def test_kalibr_relative_pose_from_t_cn_cnm1(tmp_path: Path) -> None:
    rig = load_rig(write_yaml(tmp_path / "camchain.yaml", kalibr_doc()))
    np.testing.assert_allclose(relative(rig), T_C1_C0, atol=1e-14)
    assert rig.baseline() == pytest.approx(np.linalg.norm(T_C1_C0[:3, 3]), rel=1e-12)


def test_kalibr_relative_pose_from_t_cam_imu(tmp_path: Path) -> None:
    doc = kalibr_doc()
    del doc["cam1"]["T_cn_cnm1"]
    T_c0_imu = make_transform(Rotation.from_rotvec([0.3, -1.2, 0.4]).as_matrix(), [0.05, -0.04, -0.07])
    doc["cam0"]["T_cam_imu"] = T_c0_imu.tolist()
    doc["cam1"]["T_cam_imu"] = (T_C1_C0 @ T_c0_imu).tolist()  # T_c1_imu = T_c1_c0 · T_c0_imu
    rig = load_rig(write_yaml(tmp_path / "chain.yaml", doc))
    np.testing.assert_allclose(relative(rig), T_C1_C0, atol=1e-12)


def test_kalibr_without_any_pose_still_gives_cameras(tmp_path: Path) -> None:
    doc = kalibr_doc()
    del doc["cam1"]["T_cn_cnm1"]
    path = write_yaml(tmp_path / "chain.yaml", doc)
    assert load_camera(path, "right").name == "pinhole"
    with pytest.raises(CalibrationFileError, match=r"chain\.yaml: field 'cam1\.T_cn_cnm1': missing"):
        load_rig(path)


@pytest.mark.parametrize(
    ("camera_model", "distortion", "intrinsics", "coeffs", "expected"),
    [
        (
            "omni",
            "radtan",
            [0.8, 833.0, 830.3, 373.8, 253.7],
            [-0.33, 0.13, 0.0005, 0.0006],
            {
                "model": "mei",
                "xi": 0.8,
                "fx": 833.0,
                "fy": 830.3,
                "cx": 373.8,
                "cy": 253.7,
                "k1": -0.33,
                "k2": 0.13,
                "p1": 0.0005,
                "p2": 0.0006,
                "s": 0.0,
            },
        ),
        (
            "omni",
            "none",
            [1.2, 300.0, 301.0, 320.0, 240.0],
            [],
            {
                "model": "mei",
                "xi": 1.2,
                "fx": 300.0,
                "fy": 301.0,
                "cx": 320.0,
                "cy": 240.0,
                "k1": 0.0,
                "k2": 0.0,
                "p1": 0.0,
                "p2": 0.0,
                "s": 0.0,
            },
        ),
        (
            "ds",
            "none",
            [-0.17, 0.59, 158.3, 158.2, 254.9, 256.8],
            [],
            {
                "model": "double_sphere",
                "xi": -0.17,
                "alpha": 0.59,
                "fx": 158.3,
                "fy": 158.2,
                "cx": 254.9,
                "cy": 256.8,
            },
        ),
        (
            "eucm",
            "none",
            [0.63, 1.04, 191.1, 191.0, 254.9, 256.8],
            [],
            {
                "model": "eucm",
                "alpha": 0.63,
                "beta": 1.04,
                "fx": 191.1,
                "fy": 191.0,
                "cx": 254.9,
                "cy": 256.8,
            },
        ),
        (
            "pinhole",
            "none",
            [400.0, 401.0, 320.0, 240.0],
            [],
            {
                "model": "pinhole",
                "fx": 400.0,
                "fy": 401.0,
                "cx": 320.0,
                "cy": 240.0,
                "k1": 0.0,
                "k2": 0.0,
                "p1": 0.0,
                "p2": 0.0,
            },
        ),
    ],
)
def test_kalibr_parameter_order(
    tmp_path: Path,
    camera_model: str,
    distortion: str,
    intrinsics: list[float],
    coeffs: list[float],
    expected: dict[str, Any],
) -> None:
    """Kalibr wiki: omni [xi fu fv pu pv], ds [xi alpha fu fv pu pv], eucm [alpha beta fu fv pu pv]."""
    doc = {
        "cam0": {
            "camera_model": camera_model,
            "intrinsics": intrinsics,
            "distortion_model": distortion,
            "distortion_coeffs": coeffs,
            "resolution": [640, 480],
        }
    }
    model = load_camera(write_yaml(tmp_path / "c.yaml", doc))
    assert {"model": model.name, **model.param_dict} == expected
    assert (model.width, model.height) == (640, 480)


# ----- basalt ------------------------------------------------------------------------------------
def test_basalt_cameras_and_pose(tmp_path: Path) -> None:
    doc = basalt_doc()
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(doc, indent=4))
    assert detect_format(path) == "basalt"
    left = load_camera(path, "cam0")
    kb4 = doc["value0"]["intrinsics"][0]["intrinsics"]
    assert (
        left.name == "kannala_brandt" and left.param_dict == kb4 and (left.width, left.height) == (1024, 1024)
    )
    px, ok = left.project(FRONT, in_image=False)
    np.testing.assert_allclose(
        px,
        fisheye_reference(K_of(left), [kb4[k] for k in ("k1", "k2", "k3", "k4")], FRONT),
        rtol=1e-9,
        atol=1e-9,
    )

    # UCM (basalt-headers UnifiedCamera): u = fx·x / (α·d + (1 − α)·z) + cx, per point.
    ucm = doc["value0"]["intrinsics"][1]["intrinsics"]
    right = load_camera(path, "right")
    px, ok = right.project(FRONT, in_image=False)
    a = ucm["alpha"]
    d = np.linalg.norm(FRONT, axis=1)
    den = a * d + (1 - a) * FRONT[:, 2]
    ref = np.stack([ucm["fx"] * FRONT[:, 0] / den + ucm["cx"], ucm["fy"] * FRONT[:, 1] / den + ucm["cy"]], 1)
    assert ok.all()
    np.testing.assert_allclose(px, ref, rtol=1e-12, atol=1e-9)

    # Poses: T_imu_cam as (px, py, pz, qx, qy, qz, qw); scipy reads scalar-last quaternions too.
    T = []
    for p in doc["value0"]["T_imu_cam"]:
        T.append(
            make_transform(
                Rotation.from_quat([p["qx"], p["qy"], p["qz"], p["qw"]]).as_matrix(),
                [p["px"], p["py"], p["pz"]],
            )
        )
    np.testing.assert_allclose(relative(load_rig(path)), invert_transform(T[1]) @ T[0], atol=1e-12)


# ----- CamOdoCal ---------------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".yaml", ".xml"])
def test_camodocal_kannala_brandt_matches_cv2_fisheye(tmp_path: Path, suffix: str) -> None:
    path = write_filestorage(tmp_path / f"camera{suffix}", CAMODOCAL_KB)
    assert detect_format(path) == "camodocal"
    model = load_camera(path)
    assert model == load_camera(path, "camera")
    p = CAMODOCAL_KB["projection_parameters"]
    K = np.array([[p["mu"], 0, p["u0"]], [0, p["mv"], p["v0"]], [0, 0, 1.0]])
    px, ok = model.project(FRONT, in_image=False)
    assert ok.all()
    np.testing.assert_allclose(
        px, fisheye_reference(K, [p["k2"], p["k3"], p["k4"], p["k5"]], FRONT), rtol=1e-9, atol=1e-9
    )


def test_camodocal_mei_matches_cata_camera(tmp_path: Path) -> None:
    model = load_camera(write_filestorage(tmp_path / "mei.yaml", CAMODOCAL_MEI))
    flat = {
        **CAMODOCAL_MEI["mirror_parameters"],
        **CAMODOCAL_MEI["distortion_parameters"],
        **CAMODOCAL_MEI["projection_parameters"],
    }
    near = FRONT[FRONT[:, 2] > 1.5 * np.linalg.norm(FRONT[:, :2], axis=1)]
    px, ok = model.project(near, in_image=False)
    assert ok.all() and len(near) > 20
    ref = np.array([cata_space_to_plane(flat, P) for P in near])
    np.testing.assert_allclose(px, ref, atol=1e-9)


def test_camodocal_pinhole_matches_cv2(tmp_path: Path) -> None:
    model = load_camera(write_filestorage(tmp_path / "pinhole.yaml", CAMODOCAL_PINHOLE))
    d = CAMODOCAL_PINHOLE["distortion_parameters"]
    near = FRONT[FRONT[:, 2] > 2.0 * np.linalg.norm(FRONT[:, :2], axis=1)]
    px, ok = model.project(near, in_image=False)
    assert ok.all()
    np.testing.assert_allclose(
        px, pinhole_reference(K_of(model), [d["k1"], d["k2"], d["p1"], d["p2"]], near), atol=1e-8
    )


@pytest.mark.parametrize("z_forward_file", [False, True])
def test_camodocal_scaramuzza_matches_ocam_camera(tmp_path: Path, z_forward_file: bool) -> None:
    """OCamCalib's sign (p0 < 0, z backwards) and its z-forward rewrite load as the same camera."""
    entries = json.loads(json.dumps(CAMODOCAL_SCARAMUZZA))
    poly, invpol = list(OCAM_POLY), list(OCAM_INVPOL)
    if z_forward_file:
        poly = [-a for a in poly]
        invpol = [b if i % 2 == 0 else -b for i, b in enumerate(invpol)]
        entries["poly_parameters"] = {f"p{i}": a for i, a in enumerate(poly)}
        entries["inv_poly_parameters"] = {f"p{i}": b for i, b in enumerate(invpol)}
    model = load_camera(write_filestorage(tmp_path / "ocam.yaml", entries))
    a = entries["affine_parameters"]
    flip = np.array([1.0, 1.0, 1.0 if z_forward_file else -1.0])  # file frame -> ours
    uv = np.stack(np.meshgrid(np.linspace(0, 1599, 17), np.linspace(0, 1599, 17)), -1).reshape(-1, 2)
    rays, ok = model.unproject(uv)
    assert ok.mean() > 0.9
    ref = np.array([ocam_lift(a, poly, u, v) for u, v in uv]) * flip
    np.testing.assert_allclose(rays[ok], ref[ok], atol=1e-12)
    # Projection (Newton-polished) agrees with the file's own inverse polynomial where it is good.
    px, okp = model.project(rays[ok])
    ref_px = np.array([ocam_space_to_plane(a, invpol, r * flip) for r in rays[ok]])
    central = np.linalg.norm(uv[ok] - [a["cx"], a["cy"]], axis=1) < 700
    assert okp.all() and central.sum() > 100
    assert np.abs(px - ref_px)[central].max() < 0.05


# ----- OCamCalib ---------------------------------------------------------------------------------
def test_ocamcalib_centre_convention_follows_the_comment(tmp_path: Path) -> None:
    c_path = tmp_path / "calib_results.txt"
    c_path.write_text(OCAMCALIB_TEXT)
    m_path = tmp_path / "matlab.txt"
    m_path.write_text(
        OCAMCALIB_TEXT.replace("starting from 0 (C convention)", "starting from 1 (MATLAB convention)")
    )
    c_model, m_model = load_camera(c_path), load_camera(m_path)
    assert detect_format(c_path) == "ocamcalib"
    # Row 261.744395 / column 326.939156 -> (cx, cy) = (column, row), 0-based.
    assert (c_model.param_dict["cx"], c_model.param_dict["cy"]) == (326.939156, 261.744395)
    assert m_model.param_dict["cx"] == pytest.approx(325.939156, abs=1e-12)
    assert m_model.param_dict["cy"] == pytest.approx(260.744395, abs=1e-12)
    assert (c_model.width, c_model.height) == (640, 480)


# ----- OpenCV FileStorage ------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".yaml", ".xml", ".yml"])
def test_opencv_fisheye_filestorage(tmp_path: Path, suffix: str) -> None:
    path = write_filestorage(tmp_path / f"fisheye{suffix}", opencv_fisheye_entries())
    assert detect_format(path) == "opencv"
    model = load_camera(path)
    assert model.name == "kannala_brandt" and (model.width, model.height) == (512, 512)
    px, _ = model.project(FRONT, in_image=False)
    np.testing.assert_allclose(
        px, fisheye_reference(opencv_fisheye_entries()["K"], TUM_D, FRONT), rtol=1e-9, atol=1e-9
    )


def test_opencv_omnidir_with_skew(tmp_path: Path) -> None:
    K = np.array([[758.355, 0.25, 646.72], [0.0, 757.615, 395.001], [0.0, 0.0, 1.0]])
    D = np.array([[-0.344504, 0.0984552, -0.00403995, 0.00610364]])
    path = write_filestorage(
        tmp_path / "omni.xml",
        {"K": K, "D": D, "xi": np.array([[0.894975]]), "imageSize": np.array([1280, 800])},
    )
    model = load_camera(path)
    assert {"model": model.name, **model.param_dict} == {
        "model": "mei",
        "xi": 0.894975,
        "fx": 758.355,
        "fy": 757.615,
        "cx": 646.72,
        "cy": 395.001,
        "s": 0.25,
        "k1": -0.344504,
        "k2": 0.0984552,
        "p1": -0.00403995,
        "p2": 0.00610364,
    }
    assert (model.width, model.height) == (1280, 800)


def test_opencv_pinhole_five_coefficients(tmp_path: Path) -> None:
    K = np.array([[458.654, 0, 367.215], [0, 457.296, 248.375], [0, 0, 1.0]])
    D = [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0]
    model = load_camera(
        write_filestorage(
            tmp_path / "cam.yaml",
            {
                "camera_matrix": K,
                "distortion_coefficients": np.array([D]),
                "image_size": np.array([752, 480]),
            },
        )
    )
    near = FRONT[FRONT[:, 2] > 2.0 * np.linalg.norm(FRONT[:, :2], axis=1)]
    px, _ = model.project(near, in_image=False)
    np.testing.assert_allclose(px, pinhole_reference(K, D, near), atol=1e-8)


def test_ros_camera_info_yaml(tmp_path: Path) -> None:
    """ROS camera_calibration_parsers layout: {rows, cols, data} matrices and a distortion_model."""
    doc = {
        "image_width": 512,
        "image_height": 512,
        "camera_name": "fisheye",
        "camera_matrix": {
            "rows": 3,
            "cols": 3,
            "data": [TUM_K[0], 0, TUM_K[2], 0, TUM_K[1], TUM_K[3], 0, 0, 1],
        },
        "distortion_model": "equidistant",
        "distortion_coefficients": {"rows": 1, "cols": 4, "data": TUM_D},
    }
    model = load_camera(write_yaml(tmp_path / "camera_info.yaml", doc))
    assert model.name == "kannala_brandt"
    assert model.param_dict == dict(
        zip(("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"), TUM_K + TUM_D, strict=True)
    )


@pytest.mark.parametrize("rotation_as", ["R", "om"])
def test_opencv_stereo_gives_a_rig(tmp_path: Path, rotation_as: str) -> None:
    fish = opencv_fisheye_entries()
    R, T = T_C1_C0[:3, :3], T_C1_C0[:3, 3]
    rot = {"R": R} if rotation_as == "R" else {"om": cv2.Rodrigues(R)[0]}
    path = write_filestorage(
        tmp_path / "stereo.yaml",
        {
            "K1": fish["K"],
            "D1": fish["D"],
            "K2": fish["K"],
            "D2": fish["D"],
            **rot,
            "T": T.reshape(3, 1),
            "imageSize": np.array([512, 512]),
        },
    )
    rig = load_rig(path)
    assert rig.names == ["left", "right"] and load_camera(path, "cam1") == rig.cameras["right"]
    np.testing.assert_allclose(relative(rig), T_C1_C0, atol=1e-12)
