"""Exception tree of the ``rig`` package: everything it raises on bad input or faulty hardware
derives from :class:`RigError`."""

from __future__ import annotations

__all__ = [
    "CameraFormatError",
    "CameraUnavailable",
    "CaptureTimeout",
    "ClusterError",
    "ConfigError",
    "CorruptFrameError",
    "DiskFullError",
    "EndOfStream",
    "EvaluationError",
    "FaultNotSupported",
    "LutError",
    "OutputError",
    "PipelineError",
    "RecordingError",
    "RectificationError",
    "ResourceExhausted",
    "RigError",
    "SimulationError",
    "UsbError",
]


class RigError(Exception):
    """Base of every error raised by ``rig``."""


class ConfigError(RigError, ValueError):
    """A configuration value (VPC, stereo, camera, preset) is invalid."""


class FaultNotSupported(ConfigError):
    """The camera cannot take injected faults (only file-backed cameras can)."""


class CameraUnavailable(RigError):
    """A camera cannot be opened or has stopped delivering frames."""


class CameraFormatError(CameraUnavailable):
    """The camera refused the requested format, size or frame rate."""


class CaptureTimeout(RigError):
    """No frame (or pair) arrived within the allowed time."""


class RecordingError(RigError):
    """A recording directory is malformed, incomplete or cannot be written."""


class DiskFullError(RecordingError):
    """The file system ran out of space while recording; what was written stays readable."""


class OutputError(RigError):
    """An output directory cannot be written (a full disk, no permission): the run stops, and
    every pair written before stays complete."""


class ClusterError(RigError):
    """The Dask scheduler does not answer, or the cluster cannot run the job."""


class UsbError(RigError):
    """USB enumeration failed (no libusb backend, missing permissions)."""


class LutError(RigError):
    """A lookup table cannot be built (e.g. the VPC sees nothing of a lens)."""


class PipelineError(RigError):
    """The depth pipeline was given inputs it cannot process."""


class RectificationError(RigError):
    """The scene does not support a rectification measurement or refinement (too few matches)."""


class SimulationError(RigError):
    """The virtual environment was asked for something it cannot render."""


class EvaluationError(RigError):
    """``rig evaluate`` could not complete a step."""


class ResourceExhausted(RigError):
    """The process ran out of a system resource (file descriptors): the device or file is fine,
    the process cannot open it now."""


class CorruptFrameError(RigError):
    """A frame's bytes are not a valid image (bad markers, truncated, undecodable); counted, not fatal."""


class EndOfStream(CameraUnavailable):
    """A file-backed camera reached the end of its recording (replay without loop)."""
