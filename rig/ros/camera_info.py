"""Camera calibrations in ROS's ``sensor_msgs/msg/CameraInfo`` layout (D, K, R, P), library-free.

Raw cameras: ``K`` and ``D`` describe the fisheye, ``R`` rotates its frame into the rectified
(VPC) frame and ``P`` is the rectified pinhole, as ROS's ``camera_calibration`` writes them for a
stereo pair, so OpenCV's ``initUndistortRectifyMap(K, D, R, P)`` rebuilds our rectification where
OpenCV's model can. Rectified cameras: ``plumb_bob`` with zero distortion, ``K`` the VPC's
pinhole, ``R`` the identity and the same ``P``: what ``stereo_image_proc`` reads from a rectified
pair. For the right camera ``P[0, 3] = Tx = −fx·B`` (B the baseline), the left's is 0: ``P``
projects points given in the *left* rectified frame.

Distortion models, by our camera model:

================  ==================  ===========================================================
model             distortion_model    D
================  ==================  ===========================================================
kannala_brandt    equidistant         k1, k2, k3, k4 (OpenCV ``cv2.fisheye``, as ROS 2 names it)
equidistant       equidistant         0, 0, 0, 0
pinhole           plumb_bob           k1, k2, p1, p2, 0
mei               mei                 xi, k1, k2, p1, p2 (K holds fx, skew s, fy, cx, cy)
double_sphere     double_sphere       xi, alpha
eucm              eucm                alpha, beta
scaramuzza        scaramuzza          a0, a1, … (z forward); K = [[c, d, cx], [e, 1, cy]]
================  ==================  ===========================================================

ROS has no name for the last four: their ``distortion_model`` is our model's name and ROS tools
will not undistort with them; ``D`` and ``K`` still give the exact model (formulas in
``calibration.models``).

The lat-lon rectified pair (``vpc.projection: latlon``, docs/wide-pair.md) is no pinhole either:
its rectified views' ``distortion_model`` is ``latlon`` (mrcal's name) with no ``D``, and ``K``
and ``P`` hold its ``fx, fy, cx, cy`` in pixels per radian (``u = cx + fx·asin(x/|p|)``,
``v = cy + fy·atan2(y, z)``): ROS tools that only know pinholes refuse it rather than
misproject; the point cloud and the range image carry the geometry.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from calibration.models import CameraModel
from rig.pinhole_depth import PinholeDepthView
from rig.rectified import RectifiedPair
from rig.ros.names import RosNames

__all__ = [
    "CameraInfo",
    "pinhole_depth_camera_info",
    "raw_camera_info",
    "rectified_camera_info",
    "rectified_projection",
    "stamp_json",
]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class CameraInfo:
    """ROS 2 ``CameraInfo`` without its header stamp. ``k`` (3, 3), ``r`` (3, 3), ``p`` (3, 4)."""

    frame_id: str
    width: int
    height: int
    distortion_model: str
    d: tuple[float, ...]
    k: F64
    r: F64
    p: F64

    def as_json(self, stamp_ns: int = 0) -> dict[str, Any]:
        """The message as ROS 2 names its fields (row-major flat ``k``, ``r``, ``p``)."""
        return {
            "header": {"stamp": stamp_json(stamp_ns), "frame_id": self.frame_id},
            "height": self.height,
            "width": self.width,
            "distortion_model": self.distortion_model,
            "d": list(self.d),
            "k": self.k.reshape(-1).tolist(),
            "r": self.r.reshape(-1).tolist(),
            "p": self.p.reshape(-1).tolist(),
            "binning_x": 0,
            "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
        }


def stamp_json(stamp_ns: int) -> dict[str, int]:
    """``builtin_interfaces/Time`` of a nanosecond timestamp."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return {"sec": sec, "nanosec": nanosec}


def _k(fx: float, fy: float, cx: float, cy: float, skew: float = 0.0) -> F64:
    return np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _intrinsics(model: CameraModel) -> tuple[str, tuple[float, ...], F64]:
    """``distortion_model``, ``D`` and ``K`` of ``model`` (see the module table)."""
    p = model.param_dict
    name = model.name
    if name == "scaramuzza":
        k = np.array([[p["c"], p["d"], p["cx"]], [p["e"], 1.0, p["cy"]], [0.0, 0.0, 1.0]])
        return "scaramuzza", tuple(float(a) for a in p["poly"]), k
    k = _k(p["fx"], p["fy"], p["cx"], p["cy"], p.get("s", 0.0))
    if name == "kannala_brandt":
        return "equidistant", (p["k1"], p["k2"], p["k3"], p["k4"]), k
    if name == "equidistant":
        return "equidistant", (0.0, 0.0, 0.0, 0.0), k
    if name == "pinhole":
        return "plumb_bob", (p["k1"], p["k2"], p["p1"], p["p2"], 0.0), k
    own = {"mei": ("xi", "k1", "k2", "p1", "p2"), "double_sphere": ("xi", "alpha"), "eucm": ("alpha", "beta")}
    if name in own:
        return name, tuple(float(p[n]) for n in own[name]), k
    # A model registered later: its parameters in their own order, named by the model.
    return name, tuple(float(x) for x in model.params), k


def rectified_projection(pair: RectifiedPair, camera: str) -> F64:
    """``P`` (3, 4) of ``camera``'s rectified view: the VPC pinhole (the lat-lon pair: its
    ``fx, fy, cx, cy``), ``Tx = −fx·B`` for the right camera of the pair (0 for the left)."""
    c = pair.camera
    tx = -c.fx * pair.baseline_m if camera == pair.right else 0.0
    return np.array([[c.fx, 0.0, c.cx, tx], [0.0, c.fy, c.cy, 0.0], [0.0, 0.0, 1.0, 0.0]])


def raw_camera_info(model: CameraModel, pair: RectifiedPair, camera: str, names: RosNames) -> CameraInfo:
    """The fisheye ``camera``'s CameraInfo: its own ``D``/``K``, the rectification into its VPC
    (``R = R_rect_cam``) and the rectified ``P``."""
    distortion, d, k = _intrinsics(model)
    return CameraInfo(
        frame_id=names.camera_frame(camera),
        width=model.width,
        height=model.height,
        distortion_model=distortion,
        d=tuple(float(x) for x in d),
        k=k,
        r=np.ascontiguousarray(pair.R_cam_rect[camera].T),
        p=rectified_projection(pair, camera),
    )


def rectified_camera_info(pair: RectifiedPair, camera: str, names: RosNames) -> CameraInfo:
    """``camera``'s rectified view: the VPC as plumb_bob with zero distortion (the lat-lon pair:
    ``latlon``, no ``D``; see the module doc), identity ``R``."""
    c = pair.camera
    pinhole = pair.projection == "pinhole"
    return CameraInfo(
        frame_id=names.rect_frame(camera),
        width=c.width,
        height=c.height,
        distortion_model="plumb_bob" if pinhole else "latlon",
        d=(0.0, 0.0, 0.0, 0.0, 0.0) if pinhole else (),
        k=_k(c.fx, c.fy, c.cx, c.cy),
        r=np.eye(3),
        p=rectified_projection(pair, camera),
    )


def pinhole_depth_camera_info(view: PinholeDepthView, names: RosNames) -> CameraInfo:
    """The pinhole depth image's camera (rig.pinhole_depth): ``plumb_bob`` with zero distortion in
    the left rectified view's frame, identity ``R``, ``P = [K | 0]``: what depth_image_proc, Nav2
    and RViz read."""
    c = view.camera
    k = _k(c.fx, c.fy, c.cx, c.cy)
    return CameraInfo(
        frame_id=names.rect_frame(view.pair.left),
        width=c.width,
        height=c.height,
        distortion_model="plumb_bob",
        d=(0.0, 0.0, 0.0, 0.0, 0.0),
        k=k,
        r=np.eye(3),
        p=np.hstack([k, np.zeros((3, 1))]),
    )
