"""What the rig publishes, topic by topic, as plain data: one builder for the MCAP export, the
MCAP recorder and the live Foxglove server, so all three carry the same topics and contents.

:class:`MessageBuilder` turns a pipeline's geometry and its frames into messages: the static
transforms, the raw frames with their camera infos, and for each processed pair the rectified views,
depth (REP 118), range, confidence and the point cloud, each stamped with the pair's capture time;
on a pair that is no pinhole (the lat-lon default), depth z on a pinhole cut from its range too
(:mod:`rig.pinhole_depth`), the topic pinhole-only ROS tools read correctly. The encoders
(:mod:`rig.ros.cdr` for ROS 2, ``service.foxglove`` for Foxglove's schemas) only translate these.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rig.depth import depth_to_png_mm, pack_xyzrgb
from rig.pinhole_depth import PinholeDepthConfig, PinholeDepthView
from rig.pipeline import DepthFrame, DepthPipeline, PairGeometry
from rig.recording import StoredFrame
from rig.ros.camera_info import CameraInfo, pinhole_depth_camera_info, raw_camera_info, rectified_camera_info
from rig.ros.images import RawPixels, raw_pixels
from rig.ros.names import RosNames
from rig.ros.tf import StaticTransform, static_transforms

__all__ = [
    "CameraInfoMessage",
    "CompressedImageMessage",
    "ImageMessage",
    "Message",
    "MessageBuilder",
    "PointCloudMessage",
    "TransformsMessage",
    "raw_image_message",
    "travels_compressed",
]


@dataclass(frozen=True)
class ImageMessage:
    topic: str
    frame_id: str
    stamp_ns: int
    pixels: RawPixels


@dataclass(frozen=True)
class CompressedImageMessage:
    topic: str
    frame_id: str
    stamp_ns: int
    format: str
    data: bytes


@dataclass(frozen=True)
class CameraInfoMessage:
    topic: str
    stamp_ns: int
    info: CameraInfo


@dataclass(frozen=True)
class PointCloudMessage:
    """Unordered cloud (height 1): ``points`` are :data:`rig.depth.XYZRGB_DTYPE` records."""

    topic: str
    frame_id: str
    stamp_ns: int
    points: NDArray[np.void]


@dataclass(frozen=True)
class TransformsMessage:
    topic: str
    stamp_ns: int
    transforms: list[StaticTransform]


Message = ImageMessage | CompressedImageMessage | CameraInfoMessage | PointCloudMessage | TransformsMessage


def _everything(topic: str) -> bool:
    return True


def travels_compressed(frame: StoredFrame) -> bool:
    """Whether a raw frame goes out as ``CompressedImage`` (its JPEG bytes) or as pixels."""
    return frame.format == "jpeg" and frame.raw is not None


def raw_image_message(names: RosNames, camera: str, frame: StoredFrame, stamp_ns: int) -> Message:
    """``camera``'s raw frame: JPEG bytes untouched as ``CompressedImage`` on ``…/compressed``,
    anything else (PNG, decoded frames) as its pixels."""
    frame_id = names.camera_frame(camera)
    if travels_compressed(frame) and frame.raw is not None:
        topic = names.raw_image(camera, compressed=True)
        return CompressedImageMessage(topic, frame_id, stamp_ns, "jpeg", frame.raw)
    topic = names.raw_image(camera, compressed=False)
    return ImageMessage(topic, frame_id, stamp_ns, raw_pixels(frame.decoded()))


@dataclass
class MessageBuilder:
    """Messages of one pipeline's rig (see the module docstring). ``cloud_stride``: every n-th
    pixel of each axis goes into the point cloud; ``rectified_images``: publish the rectified pair
    (a ``stereo_image_proc`` input) or only its camera infos; ``pinhole_depth``: the pinhole depth
    image's size and field (None: not published)."""

    pipeline: DepthPipeline
    names: RosNames = field(default_factory=RosNames)
    cloud_stride: int = 1
    rectified_images: bool = True
    pinhole_depth: PinholeDepthConfig | None = field(default_factory=PinholeDepthConfig)

    def __post_init__(self) -> None:
        self._built_for: PairGeometry | None = None
        self._refresh()

    def _refresh(self) -> None:
        """Camera infos and transforms of the pipeline's current geometry: an online
        rectification correction (:meth:`DepthPipeline.apply`) changes them."""
        geometry = self.pipeline.geometry
        if geometry is self._built_for:
            return
        pair, rig = geometry.pair, geometry.rig
        self.cameras = (pair.left, pair.right)
        self._raw_infos = {c: raw_camera_info(rig.cameras[c], pair, c, self.names) for c in self.cameras}
        self._rect_infos = {c: rectified_camera_info(pair, c, self.names) for c in self.cameras}
        self._transforms = static_transforms(rig, pair, self.names)
        self._pinhole: PinholeDepthView | None = None
        if self.pinhole_depth is not None and pair.projection != "pinhole":
            self._pinhole = PinholeDepthView(pair, self.pinhole_depth)
            self._pinhole_info = pinhole_depth_camera_info(self._pinhole, self.names)
        self._built_for = geometry

    @property
    def raw_infos(self) -> dict[str, CameraInfo]:
        self._refresh()
        return self._raw_infos

    @property
    def rect_infos(self) -> dict[str, CameraInfo]:
        self._refresh()
        return self._rect_infos

    @property
    def transforms(self) -> list[StaticTransform]:
        self._refresh()
        return self._transforms

    # ----- static ------------------------------------------------------------------------------
    def static(self, stamp_ns: int) -> list[Message]:
        """``/tf_static``: the whole tree in one message."""
        return [TransformsMessage(self.names.tf_static, stamp_ns, list(self.transforms))]

    # ----- raw frames --------------------------------------------------------------------------
    def raw_frame(
        self, camera: str, frame: StoredFrame, stamp_ns: int, *, want: Callable[[str], bool] = _everything
    ) -> list[Message]:
        """``camera``'s raw frame (:func:`raw_image_message`) and its camera info, those ``want``
        accepts."""
        out: list[Message] = []
        if want(self.names.raw_image(camera, compressed=travels_compressed(frame))):
            out.append(raw_image_message(self.names, camera, frame, stamp_ns))
        if want(topic := self.names.raw_info(camera)):
            out.append(CameraInfoMessage(topic, stamp_ns, self.raw_infos[camera]))
        return out

    # ----- depth -------------------------------------------------------------------------------
    def depth_image(self, frame: DepthFrame, stamp_ns: int) -> ImageMessage:
        """REP 118 depth in the left rectified frame: 32FC1 m, NaN invalid, or 16UC1 mm, 0 invalid."""
        frame_id = self.names.rect_frame(self.cameras[0])
        return ImageMessage(self.names.depth_image, frame_id, stamp_ns, self._depth_pixels(frame.depth))

    def _depth_pixels(self, depth: NDArray[np.float32]) -> RawPixels:
        """Depth in metres (NaN invalid) in the depth topics' encoding: 32FC1 m or 16UC1 mm."""
        if self.names.depth_encoding == "16UC1":
            return raw_pixels(depth_to_png_mm(depth), depth_mm=True)
        return raw_pixels(depth)

    def depth_outputs(
        self,
        frame: DepthFrame,
        stamp_ns: int,
        *,
        left_image: NDArray[Any] | Callable[[], NDArray[Any]] | None = None,
        want: Callable[[str], bool] = _everything,
    ) -> list[Message]:
        """Everything made from one processed pair: rectified views and their infos, depth and
        its info, range, confidence (when on) and the point cloud (coloured from ``left_image``,
        the left VPC view in colour or a function making it, else the frame's own view). Only
        topics ``want(topic)`` accepts are made (a live server skips what nobody watches)."""
        left, right = self.cameras
        rect_frame = self.names.rect_frame(left)
        out: list[Message] = []
        if self.rectified_images:
            for cam, img in ((left, frame.left_rect), (right, frame.right_rect)):
                if want(topic := self.names.rect_image(cam)):
                    out.append(ImageMessage(topic, self.names.rect_frame(cam), stamp_ns, raw_pixels(img)))
        infos = [(self.names.rect_info(c), self.rect_infos[c]) for c in self.cameras]
        infos.append((self.names.depth_info, self.rect_infos[left]))
        out += [CameraInfoMessage(topic, stamp_ns, info) for topic, info in infos if want(topic)]
        if want(self.names.depth_image):
            out.append(self.depth_image(frame, stamp_ns))
        out += self.pinhole_depth_outputs(frame, stamp_ns, want=want)
        if want(topic := self.names.range_image):
            out.append(ImageMessage(topic, rect_frame, stamp_ns, raw_pixels(frame.range)))
        if frame.confidence is not None and want(topic := self.names.confidence_image):
            conf = np.asarray(frame.confidence, dtype=np.float32)
            out.append(ImageMessage(topic, rect_frame, stamp_ns, raw_pixels(conf)))
        if want(self.names.points):
            colour = left_image() if callable(left_image) else left_image
            out.append(self.point_cloud(frame, stamp_ns, colour))
        return out

    def pinhole_depth_outputs(
        self, frame: DepthFrame, stamp_ns: int, *, want: Callable[[str], bool] = _everything
    ) -> list[Message]:
        """The pinhole depth image (REP 118, the depth topic's encoding) and its camera info, on
        a pair that is no pinhole; nothing on a pinhole pair (its depth topic is already that)."""
        self._refresh()
        if self._pinhole is None:
            return []
        out: list[Message] = []
        if want(topic := self.names.pinhole_depth_info):
            out.append(CameraInfoMessage(topic, stamp_ns, self._pinhole_info))
        if want(topic := self.names.pinhole_depth_image):
            pixels = self._depth_pixels(self._pinhole.depth(frame.range))
            out.append(ImageMessage(topic, self._pinhole_info.frame_id, stamp_ns, pixels))
        return out

    def point_cloud(
        self, frame: DepthFrame, stamp_ns: int, left_image: NDArray[Any] | None = None
    ) -> PointCloudMessage:
        """The valid depth pixels (every ``cloud_stride``-th) as points in the rig frame."""
        points, colors = self.pipeline.point_cloud(frame, self.cloud_stride, image=left_image)
        return PointCloudMessage(
            self.names.points, self.names.rig_frame, stamp_ns, pack_xyzrgb(points, colors)
        )
