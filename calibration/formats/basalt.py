"""basalt calibration JSON (cereal: ``{"value0": {...}}``).

``intrinsics[i] = {"camera_type", "intrinsics": {...}}`` with basalt-headers' parameter names
(kb4: fx fy cx cy k1 k2 k3 k4; ds: fx fy cx cy xi alpha; eucm: fx fy cx cy alpha beta;
pinhole: fx fy cx cy; ucm: fx fy cx cy alpha), ``resolution[i] = [width, height]`` and
``T_imu_cam[i] = {px, py, pz, qx, qy, qz, qw}`` (Hamilton quaternion, maps camera points into
the IMU frame). cam0 = left, cam1 = right.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from calibration.errors import CalibrationFileError
from calibration.formats.content import CalibrationContent, build_model
from calibration.formats.document import Document, Field
from calibration.geometry import invert_transform, make_transform
from calibration.models import CameraModel

__all__ = ["is_basalt", "quaternion_to_rotation", "read_basalt"]

F64 = NDArray[np.float64]

# camera_type -> (our model, basalt parameter names in file order)
_TYPES: dict[str, tuple[str, tuple[str, ...]]] = {
    "kb4": ("kannala_brandt", ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")),
    "ds": ("double_sphere", ("fx", "fy", "cx", "cy", "xi", "alpha")),
    "eucm": ("eucm", ("fx", "fy", "cx", "cy", "alpha", "beta")),
    "pinhole": ("pinhole", ("fx", "fy", "cx", "cy")),
    "ucm": ("mei", ("fx", "fy", "cx", "cy", "alpha")),
}
_STEREO_NAMES = ("left", "right")
# A stored quaternion may be off unit length by print round-off, not by more.
_QUATERNION_TOL = 1e-6


def _calibration_root(tree: Any) -> Any:
    return tree.get("value0", tree) if isinstance(tree, Mapping) else tree


def is_basalt(tree: Any) -> bool:
    root = _calibration_root(tree)
    return (
        isinstance(root, Mapping)
        and isinstance(root.get("intrinsics"), list)
        and ("T_imu_cam" in root or "resolution" in root)
    )


def read_basalt(doc: Document) -> CalibrationContent:
    top = Field(doc.path, doc.tree)
    root = top["value0"] if top.has("value0") else top
    intrinsics = root["intrinsics"].items()
    if not intrinsics:
        raise root["intrinsics"].error("must list at least one camera")
    resolutions = root["resolution"].items(len(intrinsics))
    cameras: dict[str, CameraModel] = {}
    aliases: dict[str, str] = {}
    for i, (cam, res) in enumerate(zip(intrinsics, resolutions, strict=True)):
        name = _STEREO_NAMES[i] if i < len(_STEREO_NAMES) else f"cam{i}"
        cameras[name] = _read_camera(cam, res)
        if name != f"cam{i}":
            aliases[f"cam{i}"] = name
    content = CalibrationContent(doc.path, "basalt", cameras, aliases)
    if len(intrinsics) >= 2:
        # A broken pose spoils load_rig only; the cameras stay usable one by one.
        try:
            poses = [_read_pose(p) for p in root["T_imu_cam"].items(len(intrinsics))]
            content.T_right_left = invert_transform(poses[1]) @ poses[0]
        except CalibrationFileError as err:
            content.pose_error = err
    return content


def _read_camera(cam: Field, res: Field) -> CameraModel:
    type_field = cam["camera_type"]
    camera_type = type_field.string()
    if camera_type not in _TYPES:
        raise type_field.error(
            f"unsupported camera_type {camera_type!r}; supported: {', '.join(sorted(_TYPES))}"
        )
    model, names = _TYPES[camera_type]
    values_field = cam["intrinsics"]
    params = {n: values_field[n].number() for n in names}
    width, height = (f.image_extent() for f in res.items(2))
    if camera_type == "ucm":
        params = _ucm_to_mei(values_field, params)
    return build_model(values_field, model, width, height, **params)


def _ucm_to_mei(where: Field, p: dict[str, float]) -> dict[str, float]:
    """basalt's UCM ``u = fx·x/(α·d + (1−α)·z) + cx`` is Mei's model without distortion:
    ``x/(z + ξ·d)`` with ξ = α/(1−α) and focal lengths fx/(1−α), fy/(1−α)."""
    alpha = p["alpha"]
    if not 0.0 <= alpha < 1.0:
        raise where.error(f"ucm alpha must be in [0, 1) to map onto the Mei model, got {alpha}")
    s = 1.0 - alpha
    return {
        "xi": alpha / s,
        "fx": p["fx"] / s,
        "fy": p["fy"] / s,
        "cx": p["cx"],
        "cy": p["cy"],
        "k1": 0.0,
        "k2": 0.0,
        "p1": 0.0,
        "p2": 0.0,
    }


def _read_pose(pose: Field) -> F64:
    t = [pose[k].number() for k in ("px", "py", "pz")]
    q = np.array([pose[k].number() for k in ("qx", "qy", "qz", "qw")])
    norm = math.hypot(*q)  # scaled: a malformed file's 1e200 does not overflow the squares
    if abs(norm - 1.0) > _QUATERNION_TOL:
        raise pose.error(f"quaternion (qx, qy, qz, qw) must have unit length, got |q| = {norm:.9g}")
    return make_transform(quaternion_to_rotation(q / norm), t)


def quaternion_to_rotation(q: F64) -> F64:
    """Unit Hamilton quaternion (qx, qy, qz, qw) (4,) -> rotation matrix (3, 3) (Eigen's convention)."""
    x, y, z, w = (float(v) for v in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
