"""``/camera_info/{left,right,rectified}``: the cameras in ROS 2's ``CameraInfo`` layout.

``left``/``right``: the fisheye cameras (their model's D and K, the rectification R into their
rectified view and its P); ``rectified``: a rectified view (``?side=left``, the default, is the
depth image's camera; ``right`` has ``Tx = −fx·B``); ``pinhole_depth``: the camera of
``/depth/pinhole`` (plumb_bob, zero D, in the left rectified frame). The same messages as the
MCAP export's and the Foxglove server's ``camera_info`` topics (see ``rig.ros.camera_info``).
"""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Query

from rig.ros.camera_info import pinhole_depth_camera_info, raw_camera_info, rectified_camera_info
from service.deps import RuntimeDep
from service.schemas import CameraInfoModel

__all__ = ["router"]

router = APIRouter(tags=["calibration"])


@router.get(
    "/camera_info/{camera}",
    response_model=CameraInfoModel,
    summary="A camera's calibration as ROS 2 sensor_msgs/msg/CameraInfo",
)
def get_camera_info(
    camera: Literal["left", "right", "rectified", "pinhole_depth"],
    runtime: RuntimeDep,
    side: Annotated[Literal["left", "right"], Query(description="which rectified view")] = "left",
) -> CameraInfoModel:
    pair = runtime.pipeline.pair
    names = runtime.settings.ros
    if camera == "rectified":
        info = rectified_camera_info(pair, pair.left if side == "left" else pair.right, names)
    elif camera == "pinhole_depth":
        info = pinhole_depth_camera_info(runtime.pinhole_view(), names)
    else:
        info = raw_camera_info(runtime.rig.cameras[camera], pair, camera, names)
    latest = runtime.store.latest
    return CameraInfoModel.model_validate(info.as_json(latest.ts_ns if latest is not None else 0))
