"""Topic names and frame ids of everything the rig publishes to ROS 2 and Foxglove (settings).

Defaults follow the ROS conventions (REP 103, REP 105, REP 118 and the ``image_pipeline``
layout), under one namespace::

    /rig/left/image_raw[/compressed]    raw fisheye frames (compressed: the camera's JPEG)
    /rig/left/camera_info               the fisheye's calibration, with the rectification R, P
    /rig/rect/left/image_rect           the rectified (VPC) views, a stereo_image_proc pair
    /rig/rect/left/camera_info          their pinhole: plumb_bob, zero distortion
    /rig/depth/image_rect               depth (REP 118), with /rig/depth/camera_info
    /rig/depth_pinhole/image_rect       depth z on a pinhole cut from the lat-lon pair's range,
                                        with /rig/depth_pinhole/camera_info (plumb_bob, zero D)
    /rig/range/image                    metres along each pixel's ray
    /rig/confidence/image               confidence in [0, 1]
    /rig/points                         point cloud in the rig frame
    /rig/health                         service health (Foxglove only, JSON)
    /tf_static                          rig_link → rig_optical_frame → cameras → rectified

A rig of N cameras (docs/ring.md) publishes each stereo pair's depth, range, confidence, rectified
views and cloud under the pair's own namespace (:meth:`RosNames.for_pair`: ``/rig/cam1_cam2/...``,
its rectified frames ``rig_cam1_cam2_cam1_rect_optical_frame``), the raw frames and camera infos
per camera as above, and::

    /rig/panorama/image                 the 360° range panorama (32FC1 m, NaN invalid)
    /rig/points                         the fused cloud (the panorama's points) in the rig frame

Frames (``frame_prefix`` "rig"): ``rig_link`` is the rig as a ROS body frame (x forward, y left,
z up: attach it to your robot's ``base_link``); ``rig_optical_frame`` is the rig frame of our
calibration (x right, y down, z forward, an optical frame in ROS's terms); the cameras and the
rectified views are optical frames too. ``remap`` renames single topics, as ROS remapping does.
"""

from __future__ import annotations

import re
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

__all__ = ["DepthEncoding", "RosNames"]

DepthEncoding = Literal["32FC1", "16UC1"]
_NAME_RE = re.compile(r"^(/[A-Za-z][A-Za-z0-9_]*)+$")
_FRAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


def _check_topic(name: str) -> str:
    if not _NAME_RE.fullmatch(name):
        raise ValueError(
            f"{name!r} is not a ROS topic name (absolute, '/'-separated tokens of letters, digits "
            "and '_', each starting with a letter)"
        )
    return name


class RosNames(BaseModel):
    """Topic names and frame ids (see the module docstring for the defaults)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    namespace: str = Field("/rig", description="namespace of every topic but /tf_static")
    frame_prefix: str = Field("rig", description="prefix of every frame id")
    remap: dict[str, str] = Field(
        default_factory=dict, description="topic → new name for single topics, e.g. {/rig/points: /points}"
    )
    depth_encoding: DepthEncoding = Field(
        "32FC1", description="depth images: 32FC1 metres with NaN invalid (REP 118), or 16UC1 mm, 0 invalid"
    )
    pair: str | None = Field(
        None, description="set by for_pair: a stereo pair of a rig of N cameras, the rectified frames' infix"
    )

    @field_validator("namespace")
    @classmethod
    def _namespace(cls, v: str) -> str:
        return _check_topic(v)

    @field_validator("frame_prefix")
    @classmethod
    def _prefix(cls, v: str) -> str:
        if not _FRAME_RE.fullmatch(v):
            raise ValueError(f"{v!r} is not a frame id prefix (letters, digits and '_', first a letter)")
        return v

    @field_validator("remap")
    @classmethod
    def _remap(cls, v: dict[str, str]) -> dict[str, str]:
        for old, new in v.items():
            _check_topic(old)
            _check_topic(new)
        return v

    def for_pair(self, label: str) -> RosNames:
        """The names of one stereo pair of a rig of N cameras (``label`` ``A-B``): its topics under
        ``namespace/A_B`` and its rectified frames named after it; cameras and the rig keep
        theirs."""
        token = label.replace("-", "_").replace(".", "_")
        return self.model_copy(update={"namespace": _check_topic(f"{self.namespace}/{token}"), "pair": token})

    # ----- topics ------------------------------------------------------------------------------
    def topic(self, relative: str) -> str:
        """``namespace/relative`` after ``remap``; ``/tf_static`` stays global."""
        name = relative if relative.startswith("/") else f"{self.namespace}/{relative}"
        return self.remap.get(name, name)

    def raw_image(self, camera: str, *, compressed: bool) -> str:
        """Raw frames of ``camera``; image_transport's ``/compressed`` for JPEG bytes."""
        return self.topic(f"{camera}/image_raw/compressed" if compressed else f"{camera}/image_raw")

    def raw_info(self, camera: str) -> str:
        return self.topic(f"{camera}/camera_info")

    def rect_image(self, camera: str) -> str:
        return self.topic(f"rect/{camera}/image_rect")

    def rect_info(self, camera: str) -> str:
        return self.topic(f"rect/{camera}/camera_info")

    @property
    def depth_image(self) -> str:
        return self.topic("depth/image_rect")

    @property
    def depth_info(self) -> str:
        return self.topic("depth/camera_info")

    @property
    def pinhole_depth_image(self) -> str:
        """z on a pinhole (rig.pinhole_depth): what depth_image_proc, Nav2 and RViz read."""
        return self.topic("depth_pinhole/image_rect")

    @property
    def pinhole_depth_info(self) -> str:
        return self.topic("depth_pinhole/camera_info")

    @property
    def range_image(self) -> str:
        return self.topic("range/image")

    @property
    def confidence_image(self) -> str:
        return self.topic("confidence/image")

    @property
    def points(self) -> str:
        return self.topic("points")

    @property
    def panorama_image(self) -> str:
        """A rig of N cameras: its 360° range panorama."""
        return self.topic("panorama/image")

    @property
    def panorama_frame(self) -> str:
        return f"{self.frame_prefix}_panorama_frame"

    @property
    def health(self) -> str:
        return self.topic("health")

    @property
    def tf_static(self) -> str:
        return self.topic("/tf_static")

    # ----- frames ------------------------------------------------------------------------------
    @property
    def body_frame(self) -> str:
        """The rig as a REP 103 body frame (x forward, y left, z up)."""
        return f"{self.frame_prefix}_link"

    @property
    def rig_frame(self) -> str:
        """Our rig frame (x right, y down, z forward): the point cloud's frame."""
        return f"{self.frame_prefix}_optical_frame"

    def camera_frame(self, camera: str) -> str:
        return f"{self.frame_prefix}_{camera}_optical_frame"

    def rect_frame(self, camera: str) -> str:
        """The rectified view (VPC) of ``camera``; the left one is the depth image's frame (of a
        rig's pair: named after the pair, a camera is in two)."""
        if self.pair is not None:
            return f"{self.frame_prefix}_{self.pair}_{camera}_rect_optical_frame"
        return f"{self.frame_prefix}_{camera}_rect_optical_frame"
