"""Capture: V4L2 and file-backed cameras behind one protocol, supervision, stereo pairing.

The service and ``rig record`` use :class:`StereoCapture`; :func:`open_camera` is the only
place that chooses a camera implementation (from the config's ``kind``).
"""

from __future__ import annotations

from rig.capture.capture import CAMERA_NAMES, StereoCapture, default_skew_gate_ns
from rig.capture.config import (
    CameraConfig,
    CaptureConfig,
    FileCameraConfig,
    PairingConfig,
    SupervisorConfig,
    V4L2CameraConfig,
    capture_config_from_mapping,
    load_capture_config,
)
from rig.capture.factory import open_camera
from rig.capture.faults import (
    CorruptFault,
    DisconnectFault,
    DropFault,
    Fault,
    RateFault,
    StallFault,
    TimestampJumpFault,
    TruncateFault,
    parse_fault,
)
from rig.capture.file_camera import FileCamera, FileCameraStats
from rig.capture.frame import Frame, FramePair
from rig.capture.health import CameraHealth, CaptureHealth, PairingHealth
from rig.capture.pairing import FramePairer
from rig.capture.protocol import Camera, CameraInfo, TimeBase
from rig.capture.supervisor import CameraSupervisor
from rig.capture.v4l2 import V4L2Camera

__all__ = [
    "CAMERA_NAMES",
    "Camera",
    "CameraConfig",
    "CameraHealth",
    "CameraInfo",
    "CameraSupervisor",
    "CaptureConfig",
    "CaptureHealth",
    "CorruptFault",
    "DisconnectFault",
    "DropFault",
    "Fault",
    "FileCamera",
    "FileCameraConfig",
    "FileCameraStats",
    "Frame",
    "FramePair",
    "FramePairer",
    "PairingConfig",
    "PairingHealth",
    "RateFault",
    "StallFault",
    "StereoCapture",
    "SupervisorConfig",
    "TimeBase",
    "TimestampJumpFault",
    "TruncateFault",
    "V4L2Camera",
    "V4L2CameraConfig",
    "capture_config_from_mapping",
    "default_skew_gate_ns",
    "load_capture_config",
    "open_camera",
    "parse_fault",
]
