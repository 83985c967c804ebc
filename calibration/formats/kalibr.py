"""Kalibr ``camchain.yaml`` / ``camchain-imucam.yaml`` / ``kalibr_imucam_chain.yaml``.

Per camera ``camN`` (Kalibr wiki "yaml formats"): ``camera_model`` (pinhole, omni, ds, eucm),
``intrinsics`` (pinhole ``[fu fv pu pv]``, omni ``[xi fu fv pu pv]``, ds ``[xi alpha fu fv pu pv]``,
eucm ``[alpha beta fu fv pu pv]``), ``distortion_model`` (radtan ``[k1 k2 r1 r2]``, equidistant
``[k1 k2 k3 k4]``, none), ``distortion_coeffs``, ``resolution [width, height]``, ``T_cn_cnm1``
(cam1: T_c1_c0, maps cam0 points into cam1) and ``T_cam_imu``. cam0 = left, cam1 = right.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from calibration.errors import CalibrationFileError
from calibration.formats.content import CalibrationContent, build_model
from calibration.formats.document import Document, Field
from calibration.geometry import invert_transform
from calibration.models import CameraModel

__all__ = ["is_kalibr", "read_kalibr"]

_CAM_KEY = re.compile(r"^cam(\d+)$")
_STEREO_NAMES = ("left", "right")

# (camera_model, distortion_model) -> (our model, intrinsics names, distortion names)
_COMBINATIONS: dict[tuple[str, str], tuple[str, tuple[str, ...], tuple[str, ...]]] = {
    ("pinhole", "equidistant"): ("kannala_brandt", ("fx", "fy", "cx", "cy"), ("k1", "k2", "k3", "k4")),
    ("pinhole", "radtan"): ("pinhole", ("fx", "fy", "cx", "cy"), ("k1", "k2", "p1", "p2")),
    ("pinhole", "none"): ("pinhole", ("fx", "fy", "cx", "cy"), ()),
    ("omni", "radtan"): ("mei", ("xi", "fx", "fy", "cx", "cy"), ("k1", "k2", "p1", "p2")),
    ("omni", "none"): ("mei", ("xi", "fx", "fy", "cx", "cy"), ()),
    ("ds", "none"): ("double_sphere", ("xi", "alpha", "fx", "fy", "cx", "cy"), ()),
    ("eucm", "none"): ("eucm", ("alpha", "beta", "fx", "fy", "cx", "cy"), ()),
}
_DISTORTION_ALIASES = {"equi": "equidistant", "radial-tangential": "radtan"}
# Models without these coefficients in Kalibr still need them set for ours.
_ZERO_DISTORTION = {"mei": ("k1", "k2", "p1", "p2")}


def is_kalibr(tree: Any) -> bool:
    if not isinstance(tree, Mapping):
        return False
    return any(
        _CAM_KEY.match(str(k)) and isinstance(v, Mapping) and ("intrinsics" in v or "camera_model" in v)
        for k, v in tree.items()
    )


def read_kalibr(doc: Document) -> CalibrationContent:
    root = Field(doc.path, doc.tree)
    indices = sorted(int(m.group(1)) for k in root.members() if (m := _CAM_KEY.match(k)))
    if indices != list(range(len(indices))):
        missing = next(i for i in range(len(indices) + 1) if i not in indices)
        raise CalibrationFileError(
            doc.path, "missing (cameras must be numbered cam0, cam1, ...)", f"cam{missing}"
        )
    cameras: dict[str, CameraModel] = {}
    aliases: dict[str, str] = {}
    for i in indices:
        key = f"cam{i}"
        name = _STEREO_NAMES[i] if i < len(_STEREO_NAMES) else key
        cameras[name] = _read_camera(root[key])
        if name != key:
            aliases[key] = name
    content = CalibrationContent(doc.path, "kalibr", cameras, aliases)
    if len(indices) >= 2:
        try:
            content.T_right_left = _pose_cam1_cam0(root)
        except CalibrationFileError as err:
            content.pose_error = err
    return content


def _read_camera(cam: Field) -> CameraModel:
    projection_field = cam["camera_model"]
    projection = projection_field.string()
    dist_field = cam.get("distortion_model")
    distortion = dist_field.string() if dist_field is not None else "none"
    distortion = _DISTORTION_ALIASES.get(distortion, distortion)
    if projection not in {p for p, _ in _COMBINATIONS}:
        known = sorted({p for p, _ in _COMBINATIONS})
        raise projection_field.error(
            f"unsupported camera_model {projection!r}; supported: {', '.join(known)}"
        )
    combo = _COMBINATIONS.get((projection, distortion))
    if combo is None:
        supported = sorted(d for p, d in _COMBINATIONS if p == projection)
        where = dist_field if dist_field is not None else cam
        raise where.error(
            f"distortion_model {distortion!r} with camera_model {projection!r} is not supported; "
            f"supported: {', '.join(supported)}"
        )
    model, intrinsic_names, distortion_names = combo
    intrinsics = cam["intrinsics"].numbers(len(intrinsic_names))
    coeffs_field = cam.get("distortion_coeffs")
    coeffs = coeffs_field.numbers() if coeffs_field is not None else []
    if len(coeffs) != len(distortion_names):
        need = len(distortion_names)
        raise (coeffs_field or cam).error(
            f"distortion_model {distortion!r} needs {need} distortion_coeffs, got {len(coeffs)}"
        )
    width, height = (f.image_extent() for f in cam["resolution"].items(2))
    params = dict(zip(intrinsic_names, intrinsics, strict=True)) | dict(
        zip(distortion_names, coeffs, strict=True)
    )
    for zero in _ZERO_DISTORTION.get(model, ()):
        params.setdefault(zero, 0.0)
    return build_model(cam, model, width, height, **params)


def _pose_cam1_cam0(root: Field) -> Any:
    """T_c1_c0 (4, 4): cam1's T_cn_cnm1, else from both cameras' T_cam_imu."""
    cam0, cam1 = root["cam0"], root["cam1"]
    chained = cam1.get("T_cn_cnm1")
    if chained is not None:
        return chained.transform()
    imu0, imu1 = cam0.get("T_cam_imu"), cam1.get("T_cam_imu")
    if imu0 is None or imu1 is None:
        raise CalibrationFileError(
            root.path, "missing (and T_cam_imu of cam0 and cam1 are not both given)", "cam1.T_cn_cnm1"
        )
    return imu1.transform() @ invert_transform(imu0.transform())
