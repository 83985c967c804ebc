"""OpenCV FileStorage calibrations (YAML or XML, also ROS ``camera_info`` YAML).

Mono: ``K`` (or ``camera_matrix``), ``D`` (or ``distortion_coefficients``), optional ``xi``
(cv::omnidir) and the image size (``image_width``/``image_height``, ``width``/``height`` or
``image_size``/``imageSize`` = [width, height]). The model:

- ``xi`` present -> mei (D = k1 k2 p1 p2, skew K[0,1] kept as ``s``);
- 4 coefficients, no xi -> kannala_brandt (cv::fisheye);
- 5 (or 8/12/14) coefficients, or an explicit ``distortion_model``/``model`` of plumb_bob / radtan /
  pinhole -> pinhole with k1 k2 p1 p2 (higher-order terms must be zero: our pinhole has none).

Stereo (cv::stereoCalibrate, cv::fisheye::stereoCalibrate, cv::omnidir::stereoCalibrate):
``K1 D1 [xi1] K2 D2 [xi2]`` (``M1``/``M2`` also accepted), ``R`` (or Rodrigues ``om``/``rvec``)
and ``T`` with ``p2 = R·p1 + T`` in metres -> a left/right rig.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.errors import CalibrationFileError
from calibration.formats.content import CalibrationContent, build_model
from calibration.formats.document import Document, Field
from calibration.geometry import make_transform
from calibration.models import CameraModel

__all__ = ["is_opencv", "read_opencv"]

F64 = NDArray[np.float64]

_K_KEYS = ("K", "camera_matrix", "cameraMatrix", "M")
_D_KEYS = ("D", "distortion_coefficients", "dist_coeffs", "distCoeffs")
_STEREO_K = {1: ("K1", "M1", "cameraMatrix1"), 2: ("K2", "M2", "cameraMatrix2")}
_STEREO_D = {1: ("D1", "distCoeffs1"), 2: ("D2", "distCoeffs2")}
_SIZE_PAIRS = (("image_width", "image_height"), ("width", "height"), ("imageWidth", "imageHeight"))
_SIZE_LISTS = ("image_size", "imageSize", "resolution", "img_size")
_FLAG_KEYS = ("distortion_model", "model", "camera_model")
_FLAGS = {
    "fisheye": "kannala_brandt",
    "equidistant": "kannala_brandt",
    "kannala_brandt": "kannala_brandt",
    "kb4": "kannala_brandt",
    "plumb_bob": "pinhole",
    "radtan": "pinhole",
    "pinhole": "pinhole",
    "omnidir": "mei",
    "omni": "mei",
    "mei": "mei",
}


def is_opencv(tree: Any) -> bool:
    return isinstance(tree, Mapping) and any(k in tree for k in (*_K_KEYS, *_STEREO_K[1]))


def read_opencv(doc: Document) -> CalibrationContent:
    root = Field(doc.path, doc.tree)
    if _first(root, _STEREO_K[1]) is not None:
        return _read_stereo(root)
    k_field = _require(root, _K_KEYS)
    d_field = _require(root, _D_KEYS)
    size = _image_size(root, _SIZE_LISTS)
    model = _camera(root, k_field, d_field, root.get("xi"), size)
    return CalibrationContent(doc.path, "opencv", {"cam0": model})


def _read_stereo(root: Field) -> CalibrationContent:
    cameras: dict[str, CameraModel] = {}
    for i, name in ((1, "left"), (2, "right")):
        size = _image_size(root, (f"imageSize{i}", f"image_size{i}", *_SIZE_LISTS))
        k_field = _require(root, _STEREO_K[i])
        d_field = _require(root, _STEREO_D[i])
        cameras[name] = _camera(root, k_field, d_field, root.get(f"xi{i}"), size)
    content = CalibrationContent(root.path, "opencv", cameras, {"cam0": "left", "cam1": "right"})
    try:
        rot = _first(root, ("R", "om", "rvec"))
        if rot is None:
            raise CalibrationFileError(root.path, "missing (or a Rodrigues vector 'om')", "R")
        if rot.name == "R":
            R = rot.rotation()
        else:
            R = np.asarray(cv2.Rodrigues(np.asarray(rot.numbers(3), dtype=np.float64))[0], dtype=np.float64)
        t = root["T"].numbers(3)
        content.T_right_left = make_transform(R, t)
    except CalibrationFileError as err:
        content.pose_error = err
    return content


def _camera(
    root: Field, k_field: Field, d_field: Field, xi_field: Field | None, size: tuple[int, int]
) -> CameraModel:
    K = k_field.matrix((3, 3))
    if K[1, 0] != 0.0 or K[2, 0] != 0.0 or K[2, 1] != 0.0 or K[2, 2] != 1.0:
        raise k_field.error("must be an upper-triangular camera matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
    fx, skew, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    D = d_field.numbers()
    flag = _flag(root)
    width, height = size
    if xi_field is not None or flag == "mei":
        if xi_field is None:
            raise CalibrationFileError(root.path, "missing (needed by the omnidir/mei model)", "xi")
        D = _pad_or_check(d_field, D, 4)
        return build_model(
            k_field,
            "mei",
            width,
            height,
            xi=xi_field.number(),
            fx=fx,
            fy=fy,
            cx=cx,
            cy=cy,
            s=skew,
            k1=D[0],
            k2=D[1],
            p1=D[2],
            p2=D[3],
        )
    if skew != 0.0:
        raise k_field.error(f"skew K[0,1] = {skew} is only supported for the omnidir (mei) model")
    if flag == "pinhole" or (flag is None and len(D) in (5, 8, 12, 14)):
        D = _pad_or_check(d_field, D, 4)
        return build_model(
            k_field, "pinhole", width, height, fx=fx, fy=fy, cx=cx, cy=cy, k1=D[0], k2=D[1], p1=D[2], p2=D[3]
        )
    if len(D) != 4:
        raise d_field.error(
            f"{len(D)} coefficients: expected 4 (fisheye, or omnidir with xi) or 5 (pinhole radtan)"
        )
    return build_model(
        k_field,
        "kannala_brandt",
        width,
        height,
        fx=fx,
        fy=fy,
        cx=cx,
        cy=cy,
        k1=D[0],
        k2=D[1],
        k3=D[2],
        k4=D[3],
    )


def _pad_or_check(d_field: Field, D: list[float], n: int) -> list[float]:
    """First ``n`` radtan coefficients; refuse non-zero higher-order terms we cannot model."""
    if len(D) < n:
        raise d_field.error(f"must have at least {n} coefficients (k1 k2 p1 p2), got {len(D)}")
    extra = [x for x in D[n:] if x != 0.0]
    if extra:
        raise d_field.error(f"higher-order coefficients {extra} are not supported (k1 k2 p1 p2 only)")
    return D[:n]


def _flag(root: Field) -> str | None:
    field = _first(root, _FLAG_KEYS)
    if field is None or not isinstance(field.value, str):
        return None
    value = field.value.strip().lower()
    if value not in _FLAGS:
        raise field.error(f"unsupported model {field.value!r}; supported: {', '.join(sorted(_FLAGS))}")
    return _FLAGS[value]


def _first(root: Field, keys: tuple[str, ...]) -> Field | None:
    for k in keys:
        f = root.get(k)
        if f is not None:
            return f
    return None


def _require(root: Field, keys: tuple[str, ...]) -> Field:
    f = _first(root, keys)
    if f is None:
        raise CalibrationFileError(root.path, f"missing (also accepted: {', '.join(keys[1:])})", keys[0])
    return f


def _image_size(root: Field, list_keys: tuple[str, ...]) -> tuple[int, int]:
    for wk, hk in _SIZE_PAIRS:
        if root.get(wk) is not None or root.get(hk) is not None:
            return root[wk].image_extent(), root[hk].image_extent()
    f = _first(root, list_keys)
    if f is None:
        raise CalibrationFileError(root.path, "missing image size (image_width/image_height or image_size)")
    w, h = f.numbers(2)
    size = Field(f.path, [w, h], f.name)
    return tuple(x.image_extent() for x in size.items(2))  # type: ignore[return-value]
