"""Sample calibration files written the way their own tools write them (yaml/json dumps of the
documented layouts, cv2.FileStorage for OpenCV and CamOdoCal), independent per-point references
transcribed from those tools, and the malformed-file helpers shared by the test_formats_* files."""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from calibration import CalibrationFileError, Rig, create, detect_format, load_camera, load_rig
from calibration.formats import dump_rig_yaml
from calibration.geometry import invert_transform, make_transform, rot_y
from calibration.models import CameraModel

RNG = np.random.default_rng(42)
# Points in front of the camera up to ~80° off axis (cv2's fisheye/pinhole references need z > 0).
_dirs = RNG.normal(size=(400, 3))
_dirs[:, 2] = np.abs(_dirs[:, 2]) + 0.2
FRONT = _dirs / np.linalg.norm(_dirs, axis=1, keepdims=True) * RNG.uniform(0.5, 5.0, (400, 1))

T_C1_C0 = make_transform(
    rot_y(np.radians(88.0)) @ Rotation.from_rotvec([0.01, -0.02, 0.005]).as_matrix(), [-0.051, 0.0012, -0.049]
)
TUM_K = [190.97847715128717, 190.9733070521226, 254.93170605935475, 256.8974428996504]
TUM_D = [0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202, 0.00020293673591811182]


# ----- sample files ------------------------------------------------------------------------------
def kalibr_doc() -> dict[str, Any]:
    return {
        "cam0": {
            "camera_model": "pinhole",
            "intrinsics": list(TUM_K),
            "distortion_model": "equidistant",
            "distortion_coeffs": list(TUM_D),
            "resolution": [512, 512],
            "rostopic": "/cam0/image_raw",
        },
        "cam1": {
            "T_cn_cnm1": T_C1_C0.tolist(),
            "camera_model": "pinhole",
            "intrinsics": [458.654, 457.296, 367.215, 248.375],
            "distortion_model": "radtan",
            "distortion_coeffs": [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
            "resolution": [752, 480],
        },
    }


def basalt_doc() -> dict[str, Any]:
    q0 = Rotation.from_rotvec([0.1, -0.7, 2.0]).as_quat()  # (x, y, z, w)
    q1 = Rotation.from_rotvec([-0.05, 0.8, 1.9]).as_quat()
    pose = [
        {"px": 0.045, "py": -0.071, "pz": -0.046, "qx": q0[0], "qy": q0[1], "qz": q0[2], "qw": q0[3]},
        {"px": -0.055, "py": -0.070, "pz": -0.049, "qx": q1[0], "qy": q1[1], "qz": q1[2], "qw": q1[3]},
    ]
    kb4 = {
        "fx": 379.045,
        "fy": 379.008,
        "cx": 505.512,
        "cy": 509.969,
        "k1": 0.00693023,
        "k2": -0.0013828,
        "k3": -0.000272596,
        "k4": -0.000452646,
    }
    ucm = {"fx": 300.0, "fy": 301.0, "cx": 320.5, "cy": 240.5, "alpha": 0.6}
    return {
        "value0": {
            "T_imu_cam": pose,
            "intrinsics": [
                {"camera_type": "kb4", "intrinsics": kb4},
                {"camera_type": "ucm", "intrinsics": ucm},
            ],
            "resolution": [[1024, 1024], [640, 480]],
            "calib_accel_bias": [0.0] * 9,
        }
    }


def write_filestorage(path: Path, entries: dict[str, Any]) -> Path:
    """Write ``entries`` with cv2.FileStorage (YAML or XML by suffix); nested dicts become maps."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)

    def put(key: str, value: Any) -> None:
        if isinstance(value, dict):
            fs.startWriteStruct(key, cv2.FileNode_MAP)
            for k, v in value.items():
                put(k, v)
            fs.endWriteStruct()
        else:
            fs.write(key, value)

    for k, v in entries.items():
        put(k, v)
    fs.release()
    return path


CAMODOCAL_KB: dict[str, Any] = {
    "model_type": "KANNALA_BRANDT",
    "camera_name": "camera",
    "image_width": 1280,
    "image_height": 960,
    "projection_parameters": {
        "k2": 3.78e-4,
        "k3": 4.48e-5,
        "k4": 5.79e-3,
        "k5": -2.41e-3,
        "mu": 285.0,
        "mv": 284.2,
        "u0": 652.3,
        "v0": 471.8,
    },
}
CAMODOCAL_MEI: dict[str, Any] = {
    "model_type": "MEI",
    "camera_name": "camera",
    "image_width": 1280,
    "image_height": 800,
    "mirror_parameters": {"xi": 0.894975},
    "distortion_parameters": {"k1": -0.344504, "k2": 0.0984552, "p1": -0.00403995, "p2": 0.00610364},
    "projection_parameters": {"gamma1": 758.355, "gamma2": 757.615, "u0": 646.72, "v0": 395.001},
}
CAMODOCAL_PINHOLE: dict[str, Any] = {
    "model_type": "PINHOLE",
    "camera_name": "cam",
    "image_width": 752,
    "image_height": 480,
    "distortion_parameters": {"k1": -0.28340811, "k2": 0.07395907, "p1": 0.00019359, "p2": 1.76187114e-05},
    "projection_parameters": {"fx": 458.654, "fy": 457.296, "cx": 367.215, "cy": 248.375},
}
# matsuren's OCamCalib numbers laid out as CamOdoCal's OCAMCamera reads them ((u, v) order).
OCAM_POLY = [-4.714441e02, 0.0, 7.356108e-04, -3.773045e-07, 5.800006e-10]
OCAM_INVPOL = [
    772.405470,
    504.754051,
    7.034666,
    45.327180,
    54.651570,
    0.458049,
    -7.873745,
    15.588713,
    13.743404,
    2.968883,
]
CAMODOCAL_SCARAMUZZA: dict[str, Any] = {
    "model_type": "SCARAMUZZA",
    "camera_name": "ocam",
    "image_width": 1600,
    "image_height": 1600,
    "poly_parameters": {f"p{i}": a for i, a in enumerate(OCAM_POLY)},
    "inv_poly_parameters": {f"p{i}": (OCAM_INVPOL[i] if i < len(OCAM_INVPOL) else 0.0) for i in range(20)},
    "affine_parameters": {
        "ac": 1.000305,
        "ad": -0.000277,
        "ae": -0.000925,
        "cx": 798.175741,
        "cy": 794.308657,
    },
}

OCAMCALIB_TEXT = """#polynomial coefficients for the DIRECT mapping function (ocam_model.ss in MATLAB). These are used by cam2world

5 -3.258881e+02 0.000000e+00 8.612196e-04 -3.553896e-08 6.737619e-09 

#polynomial coefficients for the inverse mapping function (ocam_model.invpol in MATLAB). These are used by world2cam

11 407.216320 159.672870 -53.191585 -211.811262 -963.324864 -2189.874282 -3125.470126 -2753.680698 -1427.890554 -398.461428 -46.187761 

#center: "row" and "column", starting from 0 (C convention)

261.744395 326.939156

#affine parameters "c", "d", "e"

1.001968 0.001400 0.000113

#image size: "height" and "width"

480 640

"""  # noqa: E501, W291


def opencv_fisheye_entries() -> dict[str, Any]:
    K = np.array([[TUM_K[0], 0.0, TUM_K[2]], [0.0, TUM_K[1], TUM_K[3]], [0.0, 0.0, 1.0]])
    return {"K": K, "D": np.array([TUM_D]), "image_width": 512, "image_height": 512}


# ----- references ----------------------------------------------------------------------------------
def fisheye_reference(K: np.ndarray, D: list[float], points: np.ndarray) -> np.ndarray:
    px, _ = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.asarray(D))
    return px.reshape(-1, 2)


def pinhole_reference(K: np.ndarray, D: list[float], points: np.ndarray) -> np.ndarray:
    px, _ = cv2.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.asarray(D))
    return px.reshape(-1, 2)


def cata_space_to_plane(p: dict[str, float], P: np.ndarray) -> tuple[float, float]:
    """CamOdoCal CataCamera::spaceToPlane, one point, straight from its equations."""
    z = P[2] + p["xi"] * math.sqrt(P @ P)
    mx, my = P[0] / z, P[1] / z
    r2 = mx * mx + my * my
    radial = p["k1"] * r2 + p["k2"] * r2 * r2
    dx = mx * radial + 2 * p["p1"] * mx * my + p["p2"] * (r2 + 2 * mx * mx)
    dy = my * radial + p["p1"] * (r2 + 2 * my * my) + 2 * p["p2"] * mx * my
    return p["gamma1"] * (mx + dx) + p["u0"], p["gamma2"] * (my + dy) + p["v0"]


def ocam_lift(a: dict[str, float], poly: list[float], u: float, v: float) -> np.ndarray:
    """OCAMCamera::liftProjective with the stretched offsets (the published model), unit ray."""
    xu, xv = u - a["cx"], v - a["cy"]
    inv = 1.0 / (a["ac"] - a["ad"] * a["ae"])
    x, y = inv * (xu - a["ad"] * xv), inv * (-a["ae"] * xu + a["ac"] * xv)
    rho = math.hypot(x, y)
    z = sum(c * rho**i for i, c in enumerate(poly))
    ray = np.array([x, y, z])
    return ray / np.linalg.norm(ray)


def ocam_space_to_plane(a: dict[str, float], invpol: list[float], P: np.ndarray) -> tuple[float, float]:
    """OCAMCamera::spaceToPlane, one point."""
    norm = math.hypot(P[0], P[1])
    theta = math.atan2(P[2], norm)
    rho = sum(c * theta**i for i, c in enumerate(invpol))
    x, y = P[0] / norm * rho, P[1] / norm * rho
    return x * a["ac"] + y * a["ad"] + a["cx"], x * a["ae"] + y + a["cy"]


def relative(rig: Rig) -> np.ndarray:
    return invert_transform(rig.T_rig_cam["right"]) @ rig.T_rig_cam["left"]


def K_of(model: CameraModel) -> np.ndarray:
    p = model.param_dict
    return np.array([[p["fx"], 0.0, p["cx"]], [0.0, p["fy"], p["cy"]], [0.0, 0.0, 1.0]])


def write_yaml(path: Path, doc: Any, opencv_header: bool = False) -> Path:
    path.write_text(("%YAML:1.0\n---\n" if opencv_header else "") + yaml.safe_dump(doc, sort_keys=False))
    return path


KB = create(
    "kannala_brandt",
    1280,
    960,
    fx=285.0,
    fy=284.2,
    cx=652.3,
    cy=471.8,
    k1=0.0241,
    k2=-0.0153,
    k3=0.0047,
    k4=-0.00061,
)


def rig_doc() -> dict[str, Any]:
    T = np.eye(4)
    T[0, 3] = 0.036
    Tl = T.copy()
    Tl[0, 3] = -0.036
    return yaml.safe_load(dump_rig_yaml(Rig({"left": KB, "right": KB}, {"left": Tl, "right": T})))


@dataclass(frozen=True)
class Broken:
    id: str
    write: Callable[[Path], Path]
    field: str | None
    message: str
    loader: str = "camera"


def yaml_file(
    base: Callable[[], Any], edit: Callable[[Any], None], name: str = "calib.yaml"
) -> Callable[[Path], Path]:
    def write(tmp: Path) -> Path:
        doc = copy.deepcopy(base())
        edit(doc)
        path = tmp / name
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        return path

    return write


def json_file(edit: Callable[[Any], None]) -> Callable[[Path], Path]:
    def write(tmp: Path) -> Path:
        doc = basalt_doc()
        edit(doc)
        path = tmp / "calib.json"
        path.write_text(json.dumps(doc))
        return path

    return write


def text_file(text: str | bytes, name: str = "calib.txt") -> Callable[[Path], Path]:
    def write(tmp: Path) -> Path:
        path = tmp / name
        path.write_bytes(text if isinstance(text, bytes) else text.encode())
        return path

    return write


def storage_file(
    base: dict[str, Any], edit: Callable[[dict[str, Any]], None], name: str
) -> Callable[[Path], Path]:
    def write(tmp: Path) -> Path:
        entries = copy.deepcopy(base)
        edit(entries)
        return write_filestorage(tmp / name, entries)

    return write


def setter(path: str, value: Any) -> Callable[[Any], None]:
    """Edit that sets (or with value ``DELETE`` removes) a dotted path; ints index lists."""

    def edit(doc: Any) -> None:
        keys: list[Any] = [int(k) if k.isdigit() else k for k in path.split(".")]
        node = doc
        for k in keys[:-1]:
            node = node[k]
        if value is DELETE:
            del node[keys[-1]]
        else:
            node[keys[-1]] = value

    return edit


DELETE = object()
NAN = float("nan")
ROT_SCALED = (2.0 * np.eye(4)).tolist()


def check_broken(tmp_path: Path, case: Broken) -> None:
    """The case's file raises one CalibrationFileError naming the file, the field and the reason."""
    path = case.write(tmp_path)
    with pytest.raises(CalibrationFileError) as info:
        if case.loader == "rig":
            load_rig(path)
        else:
            load_camera(path)
    err = info.value
    text = str(err)
    assert text.startswith(f"{path}: "), text
    assert err.path == path
    assert err.field == case.field, text
    if case.field is not None:
        assert f"field '{case.field}'" in text
    assert case.message in text, text
    assert "\n" not in text.strip()
    if case.loader == "camera":
        # load_rig reads the same file first, so it reports the same problem.
        with pytest.raises(CalibrationFileError) as again:
            load_rig(path)
        assert again.value.field == case.field and case.message in str(again.value)


# ----- detection by content --------------------------------------------------------------------
def test_detection_ignores_the_file_name(tmp_path: Path) -> None:
    samples = {
        "kalibr": yaml.safe_dump(kalibr_doc()),
        "basalt": json.dumps(basalt_doc()),
        "ocamcalib": OCAMCALIB_TEXT,
        "camodocal": write_filestorage(tmp_path / "k.yaml", CAMODOCAL_KB).read_text(),
        "opencv": write_filestorage(tmp_path / "o.xml", opencv_fisheye_entries()).read_text(),
    }
    for fmt, text in samples.items():
        for name in ("calibration.json", "calib_results.txt", "camchain.yaml", "noextension", "data.xml"):
            path = tmp_path / f"{fmt}-{name}"
            path.write_text(text)
            assert detect_format(path) == fmt, path.name
            assert isinstance(load_camera(path), CameraModel)
