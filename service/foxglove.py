"""The live Foxglove server: foxglove-sdk's WebSocket server (``foxglove.websocket.v1``) in
``rig serve``, publishing the rig's topics with Foxglove's schemas.

The same topics as the MCAP export (:class:`rig.ros.messages.MessageBuilder`): raw frames
(``CompressedImage`` for JPEG, ``RawImage`` otherwise), ``CameraCalibration`` of every camera,
the rectified views, depth (``RawImage`` 32FC1 m, NaN invalid), range, confidence, the point cloud
(``PointCloud`` in the rig frame, ``x y z`` float32 and ``red green blue alpha`` bytes),
``FrameTransforms`` of the rig's tree and the service's health as JSON (the ``/health`` document).

The depth worker never waits for it: a publisher thread takes the newest result from the
:class:`~service.store.ResultStore` (the worker's publish is a reference swap), at most
``max_fps`` times a second, so frames published meanwhile are skipped, not queued. Messages are
only made for topics someone subscribed to. The SDK's server runs on its own threads and queues
at most ``message_backlog`` messages per viewer, dropping the oldest: a slow viewer gets fewer
frames. Viewers reach it through :class:`~service.foxglove_gate.FoxgloveGate` on the configured
address (the SDK itself listens on an ephemeral loopback port), which bounds connections, the
handshake, idle and stalled viewers and asks for the token beyond loopback. Transforms and health
go out once a second.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import foxglove
from foxglove.channels import (
    CameraCalibrationChannel,
    CompressedImageChannel,
    FrameTransformsChannel,
    PointCloudChannel,
    RawImageChannel,
)
from foxglove.messages import (
    CameraCalibration,
    CompressedImage,
    FrameTransform,
    FrameTransforms,
    PackedElementField,
    PackedElementFieldNumericType,
    PointCloud,
    Pose,
    Quaternion,
    RawImage,
    Timestamp,
    Vector3,
)

from rig.recording import StoredFrame
from rig.ros.messages import (
    CameraInfoMessage,
    CompressedImageMessage,
    ImageMessage,
    Message,
    MessageBuilder,
    PointCloudMessage,
    TransformsMessage,
)
from rig.ros.names import RosNames
from rig.ros.ring_messages import RingMessageBuilder
from service.errors import SettingsError
from service.foxglove_gate import FoxgloveGate, GateLimits
from service.runtime import Runtime
from service.settings import FoxgloveSettings, is_loopback
from service.store import PublishedResult, ResultStore

__all__ = ["FoxgloveLive", "FoxgloveStats", "gate_limits", "start_foxglove", "to_foxglove"]

log = logging.getLogger("service.foxglove")

_STATIC_PERIOD_S = 1.0
_F32 = PackedElementFieldNumericType.Float32
_U8 = PackedElementFieldNumericType.Uint8
#: Our packed point (rig.depth.XYZRGB_DTYPE): x y z float32, then the colour bytes B G R A.
_CLOUD_FIELDS = [
    PackedElementField(name="x", offset=0, type=_F32),
    PackedElementField(name="y", offset=4, type=_F32),
    PackedElementField(name="z", offset=8, type=_F32),
    PackedElementField(name="blue", offset=12, type=_U8),
    PackedElementField(name="green", offset=13, type=_U8),
    PackedElementField(name="red", offset=14, type=_U8),
    PackedElementField(name="alpha", offset=15, type=_U8),
]
#: Foxglove calls OpenCV's fisheye model (ROS 2's ``equidistant``) ``kannala_brandt``.
_DISTORTION = {"equidistant": "kannala_brandt"}


def _time(stamp_ns: int) -> Timestamp:
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return Timestamp(sec, nsec)


def to_foxglove(message: Message) -> Any:
    """The Foxglove schema message for one of :mod:`rig.ros.messages`."""
    if isinstance(message, ImageMessage):
        px = message.pixels
        return RawImage(
            timestamp=_time(message.stamp_ns), frame_id=message.frame_id, width=px.width, height=px.height,
            encoding=px.encoding, step=px.step, data=px.data,
        )  # fmt: skip
    if isinstance(message, CompressedImageMessage):
        return CompressedImage(
            timestamp=_time(message.stamp_ns),
            frame_id=message.frame_id,
            data=message.data,
            format=message.format,
        )
    if isinstance(message, CameraInfoMessage):
        info = message.info
        return CameraCalibration(
            timestamp=_time(message.stamp_ns), frame_id=info.frame_id, width=info.width, height=info.height,
            distortion_model=_DISTORTION.get(info.distortion_model, info.distortion_model), D=list(info.d),
            K=info.k.reshape(-1).tolist(), R=info.r.reshape(-1).tolist(), P=info.p.reshape(-1).tolist(),
        )  # fmt: skip
    if isinstance(message, PointCloudMessage):
        return PointCloud(
            timestamp=_time(message.stamp_ns),
            frame_id=message.frame_id,
            pose=Pose(
                position=Vector3(x=0.0, y=0.0, z=0.0), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
            ),
            point_stride=message.points.dtype.itemsize,
            fields=_CLOUD_FIELDS,
            data=message.points.tobytes(),
        )
    assert isinstance(message, TransformsMessage)
    return FrameTransforms(
        transforms=[
            FrameTransform(
                timestamp=_time(message.stamp_ns),
                parent_frame_id=t.parent,
                child_frame_id=t.child,
                translation=Vector3(x=t.translation[0], y=t.translation[1], z=t.translation[2]),
                rotation=Quaternion(x=t.rotation[0], y=t.rotation[1], z=t.rotation[2], w=t.rotation[3]),
            )
            for t in message.transforms
        ]
    )


_CHANNELS: dict[type, Any] = {
    ImageMessage: RawImageChannel,
    CompressedImageMessage: CompressedImageChannel,
    CameraInfoMessage: CameraCalibrationChannel,
    PointCloudMessage: PointCloudChannel,
    TransformsMessage: FrameTransformsChannel,
}


def _kind_of(topic: str, names: RosNames, cameras: Sequence[str] = ("left", "right")) -> type:
    """Which message a topic carries (the raw image topics of ``cameras`` by their
    ``/compressed`` suffix; a rig's pairs' clouds by their ``/points``)."""
    if topic.endswith("/camera_info") or topic == names.depth_info:
        return CameraInfoMessage
    if topic == names.points or topic.endswith("/points"):
        return PointCloudMessage
    if topic == names.tf_static:
        return TransformsMessage
    compressed = {names.raw_image(c, compressed=True) for c in cameras}
    return CompressedImageMessage if topic in compressed else ImageMessage


@dataclass(frozen=True)
class FoxgloveStats:
    """``published``: results sent; ``skipped``: results the worker made that were never sent
    (rate limit, or newer ones arrived first); ``errors``: results that failed to publish;
    ``viewers``, ``refused``, ``dropped``: the gate's (:class:`~service.foxglove_gate.GateStats`)."""

    port: int
    published: int
    skipped: int
    errors: int
    viewers: int = 0
    refused: int = 0
    dropped: int = 0


def _stored(frame: Any, want_pixels: bool) -> StoredFrame:
    """A live frame as :class:`StoredFrame`: JPEG bytes as they are, anything else decoded
    (only when ``want_pixels``: the frame's colour image is decoded once and cached)."""
    if frame.format == "jpeg" and frame.raw is not None:
        return StoredFrame("jpeg", raw=frame.raw, source=frame.source or "")
    return StoredFrame("bgr", image=frame.image if want_pixels else None, source=frame.source or "")


class FoxgloveLive:
    """The server and its publisher thread (see the module docstring). ``health()`` returns the
    ``/health`` JSON document (bytes)."""

    def __init__(
        self,
        settings: FoxgloveSettings,
        builder: MessageBuilder | RingMessageBuilder,
        store: ResultStore,
        health: Callable[[], bytes],
        health_schema: dict[str, Any] | None = None,
        *,
        limits: GateLimits | None = None,
    ) -> None:
        self.settings = settings
        self.limits = limits or gate_limits(settings)
        self.builder = builder
        self.names = builder.names
        self.store = store
        self._health = health
        self._health_schema = health_schema or {}
        self._ctx = foxglove.Context()
        self._channels: dict[str, Any] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._server: Any = None
        self._gate: FoxgloveGate | None = None
        self._lock = threading.Lock()
        self._published = self._skipped = self._errors = 0
        self._last_stamp: int | None = None

    # ----- lifecycle ---------------------------------------------------------------------------
    def start(self) -> None:
        s = self.settings
        try:
            self._server = foxglove.start_server(
                name="odfc-rig",
                host="127.0.0.1",
                port=0,
                context=self._ctx,
                message_backlog_size=s.message_backlog,
            )
        except RuntimeError as err:
            raise SettingsError(f"server.foxglove: cannot start foxglove-sdk's server ({err})") from err
        self._gate = FoxgloveGate(s.host, s.port, int(self._server.port), self.limits)
        try:
            self._gate.start()
        except SettingsError:
            self._server.stop()
            raise
        self._health_channel = foxglove.Channel(
            self.names.health, schema=self._health_schema or None, message_encoding="json", context=self._ctx
        )
        self._thread = threading.Thread(target=self._run, name="rig-foxglove", daemon=True)
        self._thread.start()
        log.info("Foxglove server: ws://%s:%d (foxglove.websocket.v1)", s.host, self.port)

    @property
    def port(self) -> int:
        """The port viewers connect to (the gate's)."""
        return self._gate.port if self._gate is not None else 0

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        if self._gate is not None:
            self._gate.stop()
        if self._server is not None:
            self._server.stop()
            self._server = None

    def stats(self) -> FoxgloveStats:
        gate = self._gate.stats() if self._gate is not None else None
        with self._lock:
            counts = (self._published, self._skipped, self._errors)
        if gate is None:
            return FoxgloveStats(self.port, *counts)
        return FoxgloveStats(self.port, *counts, gate.viewers, gate.refused, gate.dropped)

    # ----- publishing --------------------------------------------------------------------------
    def _channel(self, topic: str) -> Any:
        channel = self._channels.get(topic)
        if channel is None:
            kind = _kind_of(topic, self.names, self.builder.cameras)
            channel = _CHANNELS[kind](topic, context=self._ctx)
            self._channels[topic] = channel
        return channel

    def _wanted(self, topic: str) -> bool:
        return bool(self._channel(topic).has_sinks())

    def _log(self, messages: list[Message], log_time: int) -> None:
        for m in messages:
            self._channel(m.topic).log(to_foxglove(m), log_time=log_time)

    def publish(self, result: PublishedResult) -> None:
        """Every subscribed topic of one result (called by the publisher thread)."""
        b, want = self.builder, self._wanted
        stamp = result.ts_ns
        messages: list[Message] = []
        if isinstance(b, RingMessageBuilder):
            ring = result.ring
            assert ring is not None  # a rig's worker publishes its sets
            for frame in ring.frames.frames:
                compressed = frame.format == "jpeg" and frame.raw is not None
                pixels = want(self.names.raw_image(frame.camera, compressed=compressed))
                messages += b.raw_frame(frame.camera, _stored(frame, pixels), frame.ts_ns, want=want)
            messages += b.set_outputs(
                ring.pairs, stamp, panorama=ring.panorama, fused_cloud=ring.rig_frame, want=want
            )
            self._log(messages, stamp)
            self._last_stamp = stamp
            return
        for cam, frame in (("left", result.left), ("right", result.right)):
            compressed = frame.format == "jpeg" and frame.raw is not None
            pixels = want(self.names.raw_image(cam, compressed=compressed))
            messages += b.raw_frame(cam, _stored(frame, pixels), frame.ts_ns, want=want)
        messages += b.depth_outputs(
            result.frame, stamp, left_image=lambda: result.rect_image("left"), want=want
        )
        self._log(messages, stamp)
        self._last_stamp = stamp

    def _publish_static(self) -> None:
        stamp = self._last_stamp if self._last_stamp is not None else time.monotonic_ns()
        if self._wanted(self.names.tf_static):
            self._log(self.builder.static(stamp), stamp)
        if self._health_channel.has_sinks():
            body = self._health()
            self._health_channel.log(json.loads(body), log_time=stamp)

    def _run(self) -> None:
        period = 1.0 / self.settings.max_fps
        last_index = 0
        next_static = 0.0
        next_frame = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                if now >= next_static:
                    next_static = now + _STATIC_PERIOD_S
                    self._publish_static()
                if now < next_frame:
                    self._stop.wait(min(next_frame, next_static) - now)
                    continue
                result = self.store.wait_newer(last_index, min(0.25, max(0.0, next_static - now)))
                if result is None:
                    continue
                skipped = result.index - last_index - 1 if last_index else 0
                last_index = result.index
                next_frame = now + period
                self.publish(result)
                with self._lock:
                    self._published += 1
                    self._skipped += max(0, skipped)
            except Exception as err:  # a viewer-side failure must not end the server's thread
                with self._lock:
                    self._errors += 1
                    first = self._errors == 1
                if first:
                    log.exception("Foxglove publisher: %s", err)
                self._stop.wait(0.1)


def gate_limits(fox: FoxgloveSettings, token: str | None = None, max_header_bytes: int = 16384) -> GateLimits:
    """The gate's limits of ``fox``; ``token`` is asked of viewers only beyond loopback."""
    return GateLimits(
        max_viewers=fox.max_viewers,
        max_header_bytes=max_header_bytes,
        handshake_timeout_s=fox.handshake_timeout_s,
        idle_timeout_s=fox.idle_timeout_s,
        stall_s=fox.stall_s,
        token=None if is_loopback(fox.host) else token,
    )


def start_foxglove(
    runtime: Runtime, health: Callable[[], bytes], health_schema: dict[str, Any]
) -> FoxgloveLive:
    """The Foxglove server of ``runtime``'s settings (``server.foxglove``), started."""
    settings = runtime.settings
    server = settings.server
    fox = server.foxglove
    token = server.api_token.get_secret_value() if server.api_token is not None else None
    limits = gate_limits(fox, token, server.max_header_bytes)
    builder: MessageBuilder | RingMessageBuilder
    if runtime.ring is not None:
        builder = RingMessageBuilder(runtime.ring, settings.ros, cloud_stride=fox.cloud_stride)
    else:
        stride, pinhole = fox.cloud_stride, settings.pinhole_depth
        builder = MessageBuilder(runtime.pipeline, settings.ros, cloud_stride=stride, pinhole_depth=pinhole)
    live = FoxgloveLive(fox, builder, runtime.store, health, health_schema, limits=limits)
    live.start()
    return live
