"""The rig's static transform tree, as ROS's ``/tf_static`` carries it.

``rig_link`` (REP 103 body frame: x forward, y left, z up) → ``rig_optical_frame`` (our rig frame:
x right, y down, z forward) → each fisheye's optical frame (``T_rig_cam`` of the calibration) →
its rectified view's optical frame (the VPC: same centre, rotated by ``R_cam_rect``). A transform
from ``parent`` to ``child`` holds the child's pose in the parent (``p_parent = T · p_child``),
as ``geometry_msgs/msg/TransformStamped`` and Foxglove's ``FrameTransform`` do.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from calibration.geometry import invert_transform, make_transform
from calibration.rig import Rig
from rig.rectified import RectifiedPair
from rig.ros.names import RosNames

__all__ = ["R_BODY_OPTICAL", "StaticTransform", "static_transforms"]

F64 = NDArray[np.float64]

#: Axes of an optical frame (x right, y down, z forward) in a REP 103 body frame (x forward,
#: y left, z up), as columns: the rotation every ROS ``*_optical_frame`` has under its ``*_link``.
R_BODY_OPTICAL: F64 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class StaticTransform:
    """``child``'s pose in ``parent``: translation (3,) metres, rotation quaternion (x, y, z, w)."""

    parent: str
    child: str
    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float]

    @classmethod
    def from_matrix(cls, parent: str, child: str, T_parent_child: F64) -> StaticTransform:
        T = np.asarray(T_parent_child, dtype=np.float64)
        x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
        if w < 0:  # one of the two equal quaternions, the one with w ≥ 0
            x, y, z, w = -x, -y, -z, -w
        t = T[:3, 3]
        return cls(
            parent, child, (float(t[0]), float(t[1]), float(t[2])), (float(x), float(y), float(z), float(w))
        )

    def matrix(self) -> F64:
        """The 4×4 ``T_parent_child`` back."""
        return make_transform(Rotation.from_quat(self.rotation).as_matrix(), self.translation)


def static_transforms(rig: Rig, pair: RectifiedPair, names: RosNames) -> list[StaticTransform]:
    """Every static transform of the rig, parents before children."""
    out = [
        StaticTransform.from_matrix(
            names.body_frame, names.rig_frame, make_transform(R_BODY_OPTICAL, np.zeros(3))
        )
    ]
    for cam in (pair.left, pair.right):
        T_rig_cam = rig.T_rig_cam[cam]
        out.append(StaticTransform.from_matrix(names.rig_frame, names.camera_frame(cam), T_rig_cam))
        T_cam_rect = invert_transform(T_rig_cam) @ pair.T_rig_rect[cam]
        out.append(StaticTransform.from_matrix(names.camera_frame(cam), names.rect_frame(cam), T_cam_rect))
    return out
