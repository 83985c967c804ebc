"""What a rig of N cameras publishes, as plain data (docs/ros.md): the messages of each stereo pair
(:class:`~rig.ros.messages.MessageBuilder` under the pair's names, :meth:`RosNames.for_pair`),
every camera's raw frame and CameraInfo, one transform tree with every camera, every pair's
rectified views and the panorama, the 360° range panorama and the fused cloud. One builder for
the MCAP export and the live Foxglove server, as for two cameras.

A camera's CameraInfo carries the rectification of the first pair it belongs to (its ``R`` and
``P``; a camera of a ring is in two pairs, each pair's rectified CameraInfos are on its own
topics).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from rig.depth import pack_xyzrgb
from rig.panorama import PanoramaFrame
from rig.pipeline import DepthFrame
from rig.recording import StoredFrame
from rig.rig_pipeline import RigFrame, RigPipeline
from rig.ros.images import raw_pixels
from rig.ros.messages import (
    CameraInfoMessage,
    ImageMessage,
    Message,
    MessageBuilder,
    PointCloudMessage,
    TransformsMessage,
    raw_image_message,
    travels_compressed,
)
from rig.ros.names import RosNames
from rig.ros.tf import StaticTransform

__all__ = ["RingMessageBuilder"]


def _everything(topic: str) -> bool:
    return True


@dataclass
class RingMessageBuilder:
    """Messages of ``ring`` (see the module docstring); ``cloud_stride`` and
    ``rectified_images`` as :class:`MessageBuilder`'s, for every pair and the fused cloud."""

    ring: RigPipeline
    names: RosNames = field(default_factory=RosNames)
    cloud_stride: int = 1
    rectified_images: bool = True

    def __post_init__(self) -> None:
        # Each pair's range, no pinhole depth: the panorama is the ring's one depth for every
        # direction (a pinhole view per pair would cost a resampling per pair per set).
        self.pairs = {
            label: MessageBuilder(
                p, self.names.for_pair(label), self.cloud_stride, self.rectified_images, pinhole_depth=None
            )
            for label, p in self.ring.pipelines.items()
        }
        # Each camera's raw CameraInfo from the first pair it belongs to.
        self._camera_pair: dict[str, MessageBuilder] = {}
        for builder in self.pairs.values():
            for camera in builder.cameras:
                self._camera_pair.setdefault(camera, builder)

    @property
    def cameras(self) -> list[str]:
        return self.ring.cameras

    def static(self, stamp_ns: int) -> list[Message]:
        """``/tf_static``: every pair's tree merged (each transform once) and the panorama's."""
        seen: dict[tuple[str, str], StaticTransform] = {}
        for builder in self.pairs.values():
            for t in builder.transforms:
                seen.setdefault((t.parent, t.child), t)
        pano = StaticTransform.from_matrix(
            self.names.rig_frame, self.names.panorama_frame, self.ring.panorama.T_rig_pano
        )
        return [TransformsMessage(self.names.tf_static, stamp_ns, [*seen.values(), pano])]

    def raw_frame(
        self, camera: str, frame: StoredFrame, stamp_ns: int, *, want: Callable[[str], bool] = _everything
    ) -> list[Message]:
        """``camera``'s raw frame on its own topic (:func:`raw_image_message`) and its
        CameraInfo (module doc), those ``want`` accepts."""
        out: list[Message] = []
        if want(self.names.raw_image(camera, compressed=travels_compressed(frame))):
            out.append(raw_image_message(self.names, camera, frame, stamp_ns))
        if want(topic := self.names.raw_info(camera)):
            out.append(CameraInfoMessage(topic, stamp_ns, self._camera_pair[camera].raw_infos[camera]))
        return out

    def set_outputs(
        self,
        pairs: Mapping[str, DepthFrame],
        stamp_ns: int,
        *,
        panorama: Callable[[], PanoramaFrame] | None = None,
        fused_cloud: Callable[[], RigFrame] | None = None,
        want: Callable[[str], bool] = _everything,
    ) -> list[Message]:
        """Every pair's outputs (its depth, range, confidence, rectified views, cloud), the
        panorama (``panorama()`` is called only when its topic is wanted: the fusion costs) and
        the fused cloud (of ``fused_cloud()``'s frame)."""
        out: list[Message] = []
        for label, builder in self.pairs.items():
            out += builder.depth_outputs(pairs[label], stamp_ns, want=want)
        if panorama is not None and want(self.names.panorama_image):
            rng = np.asarray(panorama().range, dtype=np.float32)
            frame_id = self.names.panorama_frame
            out.append(ImageMessage(self.names.panorama_image, frame_id, stamp_ns, raw_pixels(rng)))
        if fused_cloud is not None and want(self.names.points):
            points, colors = self.ring.point_cloud(fused_cloud(), self.cloud_stride)
            cloud = pack_xyzrgb(points, colors)
            out.append(PointCloudMessage(self.names.points, self.names.rig_frame, stamp_ns, cloud))
        return out
