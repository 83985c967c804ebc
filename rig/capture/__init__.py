"""Capture: V4L2 and file-backed cameras behind one protocol, supervision, stereo pairing.

The service and ``rig record`` use :class:`StereoCapture`; :func:`open_camera` is the only
place that chooses a camera implementation (from the config's ``kind``).

The names below are imported on first use: ``rig process`` reads recordings through
:mod:`rig.capture.recorded` without importing the camera drivers and supervisors.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
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
    from rig.capture.frame import Frame, FramePair, FrameSet
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
    "FrameSet",
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

_LAZY = {
    "CAMERA_NAMES": "rig.capture.capture",
    "StereoCapture": "rig.capture.capture",
    "default_skew_gate_ns": "rig.capture.capture",
    "CameraConfig": "rig.capture.config",
    "CaptureConfig": "rig.capture.config",
    "FileCameraConfig": "rig.capture.config",
    "PairingConfig": "rig.capture.config",
    "SupervisorConfig": "rig.capture.config",
    "V4L2CameraConfig": "rig.capture.config",
    "capture_config_from_mapping": "rig.capture.config",
    "load_capture_config": "rig.capture.config",
    "open_camera": "rig.capture.factory",
    "CorruptFault": "rig.capture.faults",
    "DisconnectFault": "rig.capture.faults",
    "DropFault": "rig.capture.faults",
    "Fault": "rig.capture.faults",
    "RateFault": "rig.capture.faults",
    "StallFault": "rig.capture.faults",
    "TimestampJumpFault": "rig.capture.faults",
    "TruncateFault": "rig.capture.faults",
    "parse_fault": "rig.capture.faults",
    "FileCamera": "rig.capture.file_camera",
    "FileCameraStats": "rig.capture.file_camera",
    "Frame": "rig.capture.frame",
    "FramePair": "rig.capture.frame",
    "FrameSet": "rig.capture.frame",
    "CameraHealth": "rig.capture.health",
    "CaptureHealth": "rig.capture.health",
    "PairingHealth": "rig.capture.health",
    "FramePairer": "rig.capture.pairing",
    "Camera": "rig.capture.protocol",
    "CameraInfo": "rig.capture.protocol",
    "TimeBase": "rig.capture.protocol",
    "CameraSupervisor": "rig.capture.supervisor",
    "V4L2Camera": "rig.capture.v4l2",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
