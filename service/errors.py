"""Exception tree of the ``service`` package."""

from __future__ import annotations

__all__ = ["ServiceError", "SettingsError"]


class ServiceError(Exception):
    """Base of every error raised by ``service``."""


class SettingsError(ServiceError, ValueError):
    """The service configuration (file, environment) is invalid or unsafe."""
