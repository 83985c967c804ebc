"""OCamCalib ``calib_results.txt`` (Scaramuzza's toolbox ``export_data``) -> our ``scaramuzza`` model.

The file has ``#`` comments and five lines of numbers: ``pol`` (count, a0 a1 ... with a0 < 0),
``invpol`` (count, ascending coefficients in OCamCalib's world2cam angle), the distortion
centre ``xc yc`` as (row, column), the affine ``c d e`` and ``height width``.

OCamCalib's camera frame has x along rows, y along columns and z = x × y pointing backwards;
its stretch ``A = [[c, d], [e, 1]]`` maps (x', y') to (row − xc, column − yc). Ours has x along
columns (right), y along rows (down), z forward: x = y_oc, y = x_oc, z = −z_oc, a proper rotation.
Re-expressed in (u, v) = (column, row) order the stretch is ``[[1, e], [d, c]] = c · A'`` with
``A' = [[1/c, e/c], [d/c, 1]]`` in the model's ``[[c', d'], [e', 1]]`` form. Its offsets are
(u', v') = c · (y', x'), so ρ' = c·ρ and the ray ``(y', x', −pol(ρ))`` scales to
``(u', v', −c·pol(ρ'/c))``: poly'_i = −a_i · c^(1−i); invpol' = c · invpol, a polynomial in
ψ = θ − π/2, which is world2cam's ``atan(z_oc / |xy|)`` (z_oc = −z).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

from calibration.errors import CalibrationFileError, ModelError
from calibration.formats.content import CalibrationContent
from calibration.formats.document import Document
from calibration.models import MODELS, CameraModel
from calibration.models.base import MAX_IMAGE_SIZE_PX
from calibration.models.scaramuzza import ScaramuzzaModel

__all__ = ["OCamCalibFile", "parse_ocamcalib", "read_ocamcalib", "to_scaramuzza"]

_FIELDS = ("pol", "invpol", "center", "affine", "image size")
# The line holding each scaramuzza parameter (names a ModelError's parameter in the file).
_PARAM_FIELDS = {"poly": "pol", "invpol": "invpol", "cx": "center", "cy": "center", "c": "affine"}
_PARAM_FIELDS |= {"d": "affine", "e": "affine", "width": "image size", "height": "image size"}
_ONE_BASED = re.compile(r"starting from 1|matlab convention", re.IGNORECASE)
# The most numbers each line may hold (the polynomials: the count, then the coefficients; the
# others are checked exactly after): checked before any is converted, so a line of a million does
# not cost a million floats.
_MOST_NUMBERS = dict.fromkeys(_FIELDS, 64)
_MOST_NUMBERS |= {"pol": 1 + ScaramuzzaModel.MAX_POLY_COEFFS, "invpol": 1 + ScaramuzzaModel.MAX_INVPOL_COEFFS}


@dataclass(frozen=True)
class OCamCalibFile:
    """The file's numbers as OCamCalib defines them (row/column order, z backwards, 0-based)."""

    pol: list[float]
    invpol: list[float]
    xc: float
    yc: float
    c: float
    d: float
    e: float
    height: int
    width: int


def parse_ocamcalib(doc: Document) -> OCamCalibFile:
    """The five numeric lines of ``doc`` with each one checked; errors name the line and field."""
    rows: list[tuple[int, str, list[float]]] = []
    comment = ""
    for lineno, line in enumerate(doc.text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            comment = stripped
            continue
        if len(rows) == len(_FIELDS):
            raise CalibrationFileError(doc.path, f"unexpected extra line {lineno}: {stripped[:40]!r}")
        field = _FIELDS[len(rows)]
        tokens = stripped.split(None, _MOST_NUMBERS[field])  # stops splitting past the bound
        if len(tokens) > _MOST_NUMBERS[field]:
            most = _MOST_NUMBERS[field]
            what = f" (the count and at most {most - 1} coefficients)" if field in ("pol", "invpol") else ""
            raise CalibrationFileError(doc.path, f"line {lineno}: more than {most} numbers{what}", field)
        values = []
        for token in tokens:
            try:
                value = float(token)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise CalibrationFileError(
                    doc.path, f"line {lineno}: {token!r} is not a finite number", field
                )
            values.append(value)
        rows.append((lineno, comment, values))
        comment = ""
    if len(rows) < len(_FIELDS):
        raise CalibrationFileError(doc.path, "missing (the file ends early)", _FIELDS[len(rows)])

    pol = _counted(doc, rows[0], "pol")
    invpol = _counted(doc, rows[1], "invpol")
    xc, yc = _exactly(doc, rows[2], "center", 2)
    c, d, e = _exactly(doc, rows[3], "affine", 3)
    height_f, width_f = _exactly(doc, rows[4], "image size", 2)
    if height_f != int(height_f) or width_f != int(width_f) or height_f < 1 or width_f < 1:
        raise CalibrationFileError(
            doc.path, f"line {rows[4][0]}: height and width must be positive integers", "image size"
        )
    if max(height_f, width_f) > MAX_IMAGE_SIZE_PX:
        raise CalibrationFileError(
            doc.path,
            f"line {rows[4][0]}: height and width must be at most {MAX_IMAGE_SIZE_PX}, "
            f"got {height_f:.15g} {width_f:.15g}",
            "image size",
        )
    if _ONE_BASED.search(rows[2][1]):
        xc, yc = xc - 1.0, yc - 1.0  # MATLAB's first pixel is 1
    return OCamCalibFile(pol, invpol, xc, yc, c, d, e, int(height_f), int(width_f))


def _counted(doc: Document, row: tuple[int, str, list[float]], field: str) -> list[float]:
    lineno, _, values = row
    count = values[0]
    if count != int(count) or count < 1:
        raise CalibrationFileError(
            doc.path, f"line {lineno}: first number must be the coefficient count", field
        )
    if len(values) - 1 != int(count):
        raise CalibrationFileError(
            doc.path, f"line {lineno}: declares {int(count)} coefficients but lists {len(values) - 1}", field
        )
    return values[1:]


def _exactly(doc: Document, row: tuple[int, str, list[float]], field: str, n: int) -> list[float]:
    lineno, _, values = row
    if len(values) != n:
        raise CalibrationFileError(doc.path, f"line {lineno}: expected {n} numbers, got {len(values)}", field)
    return values


def to_scaramuzza(f: OCamCalibFile) -> dict[str, Any]:
    """Our scaramuzza parameters (z forward, (u, v) order) for an OCamCalib file (module docstring)."""
    if f.c == 0.0:
        raise ModelError("affine c must not be zero")
    c = f.c
    try:
        poly = [-a * c ** (1 - i) for i, a in enumerate(f.pol)]
    except OverflowError:  # c ** -k beyond float64 (c = 1e-300): nonsense, not a traceback
        raise ModelError(f"affine c = {c:.6g} is out of range (real ones are near 1)", param="c") from None
    return {
        "poly": poly,
        "invpol": [c * b for b in f.invpol],
        "cx": f.yc,
        "cy": f.xc,
        "c": 1.0 / c,
        "d": f.e / c,
        "e": f.d / c,
    }


def read_ocamcalib(doc: Document) -> CalibrationContent:
    parsed = parse_ocamcalib(doc)
    if "scaramuzza" not in MODELS:
        raise CalibrationFileError(doc.path, "the scaramuzza camera model is not available")
    try:
        model: CameraModel = MODELS["scaramuzza"](parsed.width, parsed.height, None, **to_scaramuzza(parsed))
    except ModelError as err:
        field = _PARAM_FIELDS.get(err.param or "")
        raise CalibrationFileError(doc.path, f"not a usable OCamCalib model: {err}", field) from err
    return CalibrationContent(doc.path, "ocamcalib", {"cam0": model})
