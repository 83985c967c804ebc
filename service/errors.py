"""Exception tree of the ``service`` package.

What each becomes at the HTTP boundary (status and ``{"detail": ...}``) is decided in one place,
:mod:`service.error_handlers`; routes raise these instead of building HTTP errors themselves.
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "ApiError",
    "ConfidenceOff",
    "ConfigChanged",
    "NoPanorama",
    "NotFound",
    "NotReady",
    "RecordingConflict",
    "RecordingNameError",
    "RecordingNotFound",
    "RecordingStorageError",
    "ServiceError",
    "SettingsError",
    "StereoParamsRefused",
    "TooManyStreams",
    "Unauthorized",
    "UnknownCamera",
    "UnknownPair",
]


class ServiceError(Exception):
    """Base of every error raised by ``service``."""


class SettingsError(ServiceError, ValueError):
    """The service configuration (file, environment) is invalid or unsafe."""


class ApiError(ServiceError):
    """An HTTP request of :class:`service.client.RigClient` failed: ``status`` (0 = no response)
    and the server's ``detail`` (the ``{"detail": ...}`` body, or the transport error)."""

    def __init__(self, status: int, detail: Any, url: str = "") -> None:
        self.status = status
        self.detail = detail
        self.url = url
        where = f" {url}" if url else ""
        super().__init__(f"HTTP {status}{where}: {detail}" if status else f"request{where} failed: {detail}")


class ConfidenceOff(ServiceError):
    """The frame has no confidence map: ``stereo.confidence`` is off."""


class RecordingNameError(ServiceError, ValueError):
    """A recording name is not a plain directory name (see service.recordings.NAME_PATTERN)."""


class RecordingConflict(ServiceError):
    """The recording exists already, or another one is running."""


class RecordingStorageError(ServiceError):
    """``server.recordings_dir`` cannot hold recordings (not a directory, not writable)."""


class NotFound(ServiceError, LookupError):
    """The named thing (camera, recording, dashboard asset) does not exist."""


class RecordingNotFound(NotFound):
    """No recording (or no running recording) of that name."""


class UnknownCamera(NotFound):
    """No camera of that name (the rig has 'left' and 'right')."""


class UnknownPair(NotFound):
    """No stereo pair of that name (``A-B``); the message lists the rig's pairs."""


class NoPanorama(NotFound):
    """A panorama was asked of a two-camera rig (one pair: no 360° fusion)."""


class Unauthorized(ServiceError):
    """A state-changing request without the right bearer token (or with none configured)."""


class NotReady(ServiceError):
    """Nothing to answer with yet: the service is starting, or no pair has been processed."""


class TooManyStreams(ServiceError):
    """``server.max_streams`` clients are streaming already."""


class ConfigChanged(ServiceError):
    """A conditional change (``If-Match``) of a configuration revision that is no longer current."""


class StereoParamsRefused(ServiceError, ValueError):
    """A stereo parameter change was refused (invalid value, or the matcher rejects it).
    ``detail`` is the message, or pydantic's list of field errors with their ``loc``."""

    def __init__(self, detail: str | list[dict[str, Any]]) -> None:
        self.detail = detail
        super().__init__(detail if isinstance(detail, str) else f"{len(detail)} invalid field(s)")
