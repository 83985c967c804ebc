"""Exception tree of the ``calibration`` package.

Everything this package raises on bad input derives from :class:`CalibrationError`, so callers
(the CLI, the service) can translate one type at their boundary.
"""

from __future__ import annotations

from pathlib import Path

__all__ = [
    "CalibrationError",
    "CalibrationFailed",
    "CalibrationFileError",
    "ModelError",
]


class CalibrationError(Exception):
    """Base of every error raised by ``calibration``."""


class ModelError(CalibrationError, ValueError):
    """A camera model was asked for with an unknown name or invalid parameters.

    ``param`` names the parameter at fault when there is one (``"width"``, ``"poly"``, ...), so a
    file reader can name the field that holds it.
    """

    def __init__(self, message: str, param: str | None = None) -> None:
        super().__init__(message)
        self.param = param


class CalibrationFileError(CalibrationError):
    """A calibration file could not be read: names the file and, where known, the field."""

    def __init__(self, path: str | Path, message: str, field: str | None = None) -> None:
        self.path = Path(path)
        self.field = field
        self.reason = message
        where = f"{self.path}" + (f": field '{field}'" if field else "")
        super().__init__(f"{where}: {message}")


class CalibrationFailed(CalibrationError):
    """Calibration could not produce a result (too few usable views, no convergence)."""
