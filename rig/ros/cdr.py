"""The messages of :mod:`rig.ros.messages` as ROS 2 messages: type names, ``.msg`` definitions
(the ``ros2msg`` schemas of MCAP's ROS 2 profile) and CDR bytes.

Types and definitions are ROS 2 Humble's, from ``rosbags``' type store (the same for these
messages in every ROS 2 distribution since); serialisation is rosbags' CDR (little-endian).
Depth and the other float images are ``32FC1`` (``16UC1`` mm for depth on request); the point
cloud is ``x y z`` FLOAT32 and PCL's packed ``rgb`` (FLOAT32 bits of 0xAARRGGBB), 16 bytes a point.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from rig.ros.camera_info import CameraInfo
from rig.ros.messages import (
    CameraInfoMessage,
    CompressedImageMessage,
    ImageMessage,
    Message,
    PointCloudMessage,
    TransformsMessage,
)

__all__ = ["ROS_TYPES", "msgdef", "ros_type", "serialize", "typestore"]

#: Message type of each kind of message.
ROS_TYPES: dict[type, str] = {
    ImageMessage: "sensor_msgs/msg/Image",
    CompressedImageMessage: "sensor_msgs/msg/CompressedImage",
    CameraInfoMessage: "sensor_msgs/msg/CameraInfo",
    PointCloudMessage: "sensor_msgs/msg/PointCloud2",
    TransformsMessage: "tf2_msgs/msg/TFMessage",
}


@functools.cache
def typestore() -> Typestore:
    return get_typestore(Stores.ROS2_HUMBLE)


def ros_type(message: Message) -> str:
    return ROS_TYPES[type(message)]


@functools.cache
def msgdef(typename: str) -> str:
    """The ``.msg`` definition of ``typename`` with its dependencies appended, as rosbag2 stores it."""
    text, _ = typestore().generate_msgdef(typename, ros_version=2)
    return text


def _t(name: str) -> Any:
    return typestore().types[name]


def _header(stamp_ns: int, frame_id: str) -> Any:
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return _t("std_msgs/msg/Header")(
        stamp=_t("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec), frame_id=frame_id
    )


def _u8(data: bytes) -> np.ndarray[Any, np.dtype[np.uint8]]:
    return np.frombuffer(data, dtype=np.uint8)


def _camera_info(info: CameraInfo, stamp_ns: int) -> Any:
    roi = _t("sensor_msgs/msg/RegionOfInterest")(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return _t("sensor_msgs/msg/CameraInfo")(
        header=_header(stamp_ns, info.frame_id),
        height=info.height,
        width=info.width,
        distortion_model=info.distortion_model,
        d=np.asarray(info.d, dtype=np.float64),
        k=np.asarray(info.k, dtype=np.float64).reshape(9),
        r=np.asarray(info.r, dtype=np.float64).reshape(9),
        p=np.asarray(info.p, dtype=np.float64).reshape(12),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def _point_cloud(m: PointCloudMessage) -> Any:
    field = _t("sensor_msgs/msg/PointField")
    fields = [
        field(name=n, offset=4 * i, datatype=field.FLOAT32, count=1)
        for i, n in enumerate(("x", "y", "z", "rgb"))
    ]
    n = int(m.points.shape[0])
    step = m.points.dtype.itemsize
    return _t("sensor_msgs/msg/PointCloud2")(
        header=_header(m.stamp_ns, m.frame_id),
        height=1,
        width=n,
        fields=fields,
        is_bigendian=False,
        point_step=step,
        row_step=step * n,
        data=np.ascontiguousarray(m.points).view(np.uint8).reshape(-1),
        is_dense=True,
    )


def _transforms(m: TransformsMessage) -> Any:
    out = []
    for tf in m.transforms:
        t, q = tf.translation, tf.rotation
        transform = _t("geometry_msgs/msg/Transform")(
            translation=_t("geometry_msgs/msg/Vector3")(x=t[0], y=t[1], z=t[2]),
            rotation=_t("geometry_msgs/msg/Quaternion")(x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        out.append(
            _t("geometry_msgs/msg/TransformStamped")(
                header=_header(m.stamp_ns, tf.parent), child_frame_id=tf.child, transform=transform
            )
        )
    return _t("tf2_msgs/msg/TFMessage")(transforms=out)


def to_ros(message: Message) -> Any:
    """The rosbags message object of ``message``."""
    if isinstance(message, ImageMessage):
        px = message.pixels
        return _t("sensor_msgs/msg/Image")(
            header=_header(message.stamp_ns, message.frame_id),
            height=px.height,
            width=px.width,
            encoding=px.encoding,
            is_bigendian=0,
            step=px.step,
            data=_u8(px.data),
        )
    if isinstance(message, CompressedImageMessage):
        return _t("sensor_msgs/msg/CompressedImage")(
            header=_header(message.stamp_ns, message.frame_id), format=message.format, data=_u8(message.data)
        )
    if isinstance(message, CameraInfoMessage):
        return _camera_info(message.info, message.stamp_ns)
    if isinstance(message, PointCloudMessage):
        return _point_cloud(message)
    return _transforms(message)


def serialize(message: Message) -> bytes:
    """CDR bytes of ``message`` (little-endian, with the 4-byte encapsulation header)."""
    return bytes(typestore().serialize_cdr(to_ros(message), ros_type(message)))
