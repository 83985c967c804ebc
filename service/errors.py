"""Exception tree of the ``service`` package."""

from __future__ import annotations

from typing import Any

__all__ = [
    "ApiError",
    "ConfidenceOff",
    "RecordingConflict",
    "RecordingNameError",
    "RecordingNotFound",
    "ServiceError",
    "SettingsError",
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


class RecordingNotFound(ServiceError):
    """No recording (or no running recording) of that name."""
