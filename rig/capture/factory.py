"""The one place that turns a camera config into a camera: ``kind`` decides, nothing else does."""

from __future__ import annotations

from rig.capture.config import CameraConfig, FileCameraConfig, V4L2CameraConfig
from rig.capture.file_camera import FileCamera
from rig.capture.protocol import Camera, TimeBase
from rig.capture.v4l2 import V4L2Camera
from rig.errors import ConfigError

__all__ = ["open_camera"]


def open_camera(config: CameraConfig, name: str, *, timebase: TimeBase | None = None) -> Camera:
    """Build the camera ``config`` describes (not yet opened: its supervisor opens it).

    ``timebase`` is shared by the cameras of one capture so replayed "live" timestamps of the
    two cameras come from one clock; hardware cameras have their own clock and ignore it.
    """
    if isinstance(config, V4L2CameraConfig):
        return V4L2Camera(config, name)
    if isinstance(config, FileCameraConfig):
        return FileCamera(config, name, timebase=timebase)
    raise ConfigError(f"camera {name}: unknown camera kind {getattr(config, 'kind', None)!r}")
