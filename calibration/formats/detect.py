"""Which format a file is, decided from its content (never from its name alone)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from calibration.errors import CalibrationFileError
from calibration.formats.basalt import is_basalt, read_basalt
from calibration.formats.camodocal import is_camodocal, read_camodocal
from calibration.formats.content import CalibrationContent
from calibration.formats.document import Document, read_document
from calibration.formats.kalibr import is_kalibr, read_kalibr
from calibration.formats.ocamcalib import read_ocamcalib
from calibration.formats.opencv import is_opencv, read_opencv
from calibration.formats.rig_yaml import is_rig_yaml, read_rig_yaml

__all__ = ["FORMATS", "detect_format", "read_calibration"]

Reader = Callable[[Document], CalibrationContent]

# Checked in this order on the parsed tree; the first match reads the file.
_TREE_FORMATS: tuple[tuple[str, Callable[[object], bool], Reader], ...] = (
    ("rig.yaml", is_rig_yaml, read_rig_yaml),
    ("kalibr", is_kalibr, read_kalibr),
    ("basalt", is_basalt, read_basalt),
    ("camodocal", is_camodocal, read_camodocal),
    ("opencv", is_opencv, read_opencv),
)
FORMATS = (*(name for name, _, _ in _TREE_FORMATS), "ocamcalib")
_DESCRIPTION = (
    "rig.yaml, Kalibr camchain, basalt calibration JSON, CamOdoCal YAML, OCamCalib calib_results.txt, "
    "OpenCV FileStorage (K, D[, xi])"
)


def _pick(doc: Document) -> tuple[str, Reader]:
    if doc.kind == "text":
        return "ocamcalib", read_ocamcalib
    for name, matches, reader in _TREE_FORMATS:
        if matches(doc.tree):
            return name, reader
    raise CalibrationFileError(doc.path, f"not a calibration file of a known format ({_DESCRIPTION})")


def detect_format(path: str | Path) -> str:
    """One of :data:`FORMATS`; CalibrationFileError if the file is unreadable or of no known format."""
    return _pick(read_document(path))[0]


def read_calibration(path: str | Path) -> CalibrationContent:
    """Parse any supported calibration file into cameras (+ poses)."""
    doc = read_document(path)
    return _pick(doc)[1](doc)
