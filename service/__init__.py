"""The depth service: FastAPI app, settings, worker and typed client (``rig serve`` is in ``cli``).

``create_app``, ``Settings``, ``load_settings`` and ``RigClient`` are imported on first use, so
``import service`` (and ``rig --help``) stays cheap and builds nothing.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from service.app import create_app
    from service.client import RigClient
    from service.settings import Settings, load_settings

__all__ = ["RigClient", "Settings", "create_app", "load_settings"]

_LAZY = {
    "create_app": "service.app",
    "RigClient": "service.client",
    "Settings": "service.settings",
    "load_settings": "service.settings",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'service' has no attribute {name!r}")
