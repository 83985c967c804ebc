"""Reading a calibration file into a plain tree, and typed access to its fields.

:func:`read_document` turns any supported file (JSON, YAML including OpenCV's ``%YAML:1.0`` dialect
with ``!!opencv-matrix`` tags, OpenCV FileStorage XML, or OCamCalib's plain text) into a
:class:`Document`. :class:`Field` wraps one value of that tree with its dotted path so every
malformed value raises one :class:`CalibrationFileError` naming the file and the field.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from calibration.errors import CalibrationFileError
from calibration.formats.parse import MAX_FILE_BYTES, TaggedMatrix, parse_text
from calibration.geometry import is_rotation
from calibration.models.base import MAX_IMAGE_SIZE_PX
from calibration.rig import translation_problem

__all__ = ["MAX_FILE_BYTES", "Document", "Field", "TaggedMatrix", "read_document"]

F64 = NDArray[np.float64]

# Rotation blocks must be orthonormal to this (published calibrations print ~16 digits).
_ROTATION_TOL = 1e-6


@dataclass(frozen=True)
class Document:
    """``kind`` is "json", "yaml", "xml" or "text"; ``tree`` the parsed content (None for text)."""

    path: Path
    kind: str
    text: str
    tree: Any


def read_document(path: str | Path) -> Document:
    """Read and parse ``path``; raise CalibrationFileError for a missing, binary or unparsable file."""
    p = Path(path)
    try:
        if p.is_dir():
            raise CalibrationFileError(p, "is a directory, not a calibration file")
        if p.exists() and not p.is_file():
            raise CalibrationFileError(p, "is not a regular file")
        size = p.stat().st_size
        if size > MAX_FILE_BYTES:
            raise CalibrationFileError(p, f"{size} bytes is too large for a calibration file")
        raw = p.read_bytes()
    except FileNotFoundError as err:
        raise CalibrationFileError(p, "file not found") from err
    except OSError as err:
        raise CalibrationFileError(p, f"cannot read: {err.strerror or err}") from err
    if not raw.strip():
        raise CalibrationFileError(p, "file is empty")
    if b"\x00" in raw:
        raise CalibrationFileError(p, "binary content, not a calibration file")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise CalibrationFileError(p, f"not UTF-8 text (byte {err.start}), not a calibration file") from err
    kind, tree = parse_text(p, text)
    return Document(p, kind, text, tree)


# ----- typed field access -------------------------------------------------------------------------
class Field:
    """One value of a parsed file with its dotted path, e.g. ``cameras.left.params.fx``.

    Every accessor either returns a clean Python/numpy value or raises CalibrationFileError
    naming the file and this field.
    """

    def __init__(self, path: Path, value: Any, name: str = "") -> None:
        self.path = path
        self.value = value
        self.name = name

    def error(self, message: str) -> CalibrationFileError:
        return CalibrationFileError(self.path, message, self.name or None)

    def _child_name(self, key: str | int) -> str:
        if isinstance(key, int):
            return f"{self.name}[{key}]"
        return f"{self.name}.{key}" if self.name else str(key)

    # ----- structure ------------------------------------------------------------------------------
    def is_mapping(self) -> bool:
        return isinstance(self.value, Mapping)

    def mapping(self) -> Mapping[str, Any]:
        """The value as a mapping with string keys (YAML may give ``0:`` as an int key)."""
        if not isinstance(self.value, Mapping):
            raise self.error(f"must be a mapping, got {_describe(self.value)}")
        return {str(k): v for k, v in self.value.items()}

    def has(self, key: str) -> bool:
        return isinstance(self.value, Mapping) and key in self.mapping()

    def __getitem__(self, key: str) -> Field:
        m = self.mapping()
        if key not in m:
            raise CalibrationFileError(self.path, "missing", self._child_name(key))
        return Field(self.path, m[key], self._child_name(key))

    def get(self, key: str) -> Field | None:
        """The child ``key``, or None when absent (or null)."""
        m = self.mapping()
        if m.get(key) is None:
            return None
        return Field(self.path, m[key], self._child_name(key))

    def members(self) -> list[str]:
        """Keys of a mapping, as strings."""
        return [str(k) for k in self.mapping()]

    def items(self, length: int | None = None) -> list[Field]:
        """Elements of a sequence as Fields (``name[i]``); ``length`` if given must match."""
        if not isinstance(self.value, list | tuple):
            raise self.error(f"must be a list, got {_describe(self.value)}")
        if length is not None and len(self.value) != length:
            raise self.error(f"must have {length} entries, got {len(self.value)}")
        return [Field(self.path, v, self._child_name(i)) for i, v in enumerate(self.value)]

    # ----- scalars --------------------------------------------------------------------------------
    def number(self) -> float:
        """A finite real number (ints accepted, booleans and strings refused)."""
        v = self.value
        if isinstance(v, TaggedMatrix):
            arr = self.matrix()
            if arr.size != 1:
                raise self.error(f"must be a number, got a {arr.shape[0]}x{arr.shape[1]} matrix")
            v = float(arr.reshape(-1)[0])
        if isinstance(v, bool) or not isinstance(v, int | float | np.floating | np.integer):
            raise self.error(f"must be a number, got {_describe(v)}")
        try:
            f = float(v)
        except OverflowError:
            f = math.inf  # an integer beyond float range
        if not math.isfinite(f):
            raise self.error(f"must be finite, got {f}")
        return f

    def integer(self, minimum: int | None = None, maximum: int | None = None) -> int:
        f = self.number()
        if f != int(f):
            raise self.error(f"must be an integer, got {f!r}")
        i = int(f)
        if minimum is not None and i < minimum:
            raise self.error(f"must be at least {minimum}, got {i}")
        if maximum is not None and i > maximum:
            raise self.error(f"must be at most {maximum}, got {f:.15g}")  # no 200-digit integers
        return i

    def image_extent(self) -> int:
        """An image width or height in pixels: 1 to the models' ``MAX_IMAGE_SIZE_PX``."""
        return self.integer(minimum=1, maximum=MAX_IMAGE_SIZE_PX)

    def string(self) -> str:
        if not isinstance(self.value, str):
            raise self.error(f"must be a string, got {_describe(self.value)}")
        return self.value

    # ----- arrays ---------------------------------------------------------------------------------
    def numbers(self, count: int | tuple[int, ...] | None = None) -> list[float]:
        """A flat list of finite numbers: a YAML/JSON list or any OpenCV matrix/vector."""
        if isinstance(self.value, TaggedMatrix | np.ndarray) or _is_plain_matrix(self.value):
            values = [float(x) for x in self.matrix().reshape(-1)]
        else:
            values = [f.number() for f in self.items()]
        allowed = (count,) if isinstance(count, int) else count
        if allowed is not None and len(values) not in allowed:
            want = " or ".join(str(n) for n in allowed)
            raise self.error(f"must have {want} entries, got {len(values)}")
        return values

    def matrix(self, shape: tuple[int, int] | None = None) -> F64:
        """A finite 2-D matrix from nested lists, ``!!opencv-matrix``, ROS-style
        ``{rows, cols, data}`` or an OpenCV XML matrix; ``shape`` if given must match."""
        v = self.value
        if isinstance(v, TaggedMatrix):
            v = v.content
        if isinstance(v, np.ndarray):
            arr = np.atleast_2d(np.asarray(v, dtype=np.float64))
            if arr.size == 0:
                raise self.error("must be a non-empty matrix")
            arr = arr.reshape(arr.shape[0], -1)  # multi-channel mats (rows, cols, ch) -> (rows, cols*ch)
        elif isinstance(v, Mapping):
            arr = self._rows_cols_data(v)
        elif isinstance(v, list | tuple):
            arr = self._nested_lists(v)
        else:
            raise self.error(f"must be a matrix, got {_describe(v)}")
        if not np.isfinite(arr).all():
            raise self.error("must contain finite numbers only")
        if shape is not None and arr.shape != shape:
            raise self.error(f"must be a {shape[0]}x{shape[1]} matrix, got {arr.shape[0]}x{arr.shape[1]}")
        return arr

    def _rows_cols_data(self, m: Mapping[str, Any]) -> F64:
        if "sizes" in m and "rows" not in m:
            return self._nd_matrix(m)
        for key in ("rows", "cols", "data"):
            if key not in m:
                raise CalibrationFileError(self.path, "missing", self._child_name(key))
        rows = Field(self.path, m["rows"], self._child_name("rows")).integer(minimum=1)
        cols = Field(self.path, m["cols"], self._child_name("cols")).integer(minimum=1)
        data = Field(self.path, m["data"], self._child_name("data")).numbers()
        dt = m.get("dt")
        # OpenCV's dt is "[channels]type", e.g. "d" or "2f"; plain {rows, cols, data} has one channel.
        channels = int(dt[0]) if isinstance(dt, str) and dt[:1].isdigit() else 1
        if len(data) != rows * cols * channels:
            raise CalibrationFileError(
                self.path,
                f"has {len(data)} entries, rows*cols*channels = {rows * cols * channels}",
                self._child_name("data"),
            )
        return np.asarray(data, dtype=np.float64).reshape(rows, cols * channels)

    def _nd_matrix(self, m: Mapping[str, Any]) -> F64:
        """``!!opencv-nd-matrix`` ``{sizes, dt, data}``: 1-D as a row, 2-D as is."""
        if "data" not in m:
            raise CalibrationFileError(self.path, "missing", self._child_name("data"))
        sizes = [
            f.integer(minimum=1) for f in Field(self.path, m["sizes"], self._child_name("sizes")).items()
        ]
        data = Field(self.path, m["data"], self._child_name("data")).numbers()
        if len(sizes) not in (1, 2) or len(data) != math.prod(sizes):
            raise self.error(f"must be a 1-D or 2-D matrix with {sizes} entries, got {len(data)} numbers")
        return np.asarray(data, dtype=np.float64).reshape(sizes[0] if len(sizes) == 2 else 1, -1)

    def _nested_lists(self, v: list[Any] | tuple[Any, ...]) -> F64:
        if not v:
            raise self.error("must be a non-empty matrix")
        if all(isinstance(r, list | tuple) for r in v):
            rows = [Field(self.path, r, self._child_name(i)).numbers() for i, r in enumerate(v)]
            widths = {len(r) for r in rows}
            if len(widths) != 1:
                raise self.error("rows must all have the same length")
            return np.asarray(rows, dtype=np.float64)
        return np.asarray([self.numbers()], dtype=np.float64)

    def transform(self) -> F64:
        """A rigid 4x4 transform: orthonormal rotation with det +1, last row [0, 0, 0, 1]."""
        T = self.matrix((4, 4))
        check_rigid(self, T[:3, :3])
        problem = translation_problem(T[:3, 3])
        if problem is not None:
            raise self.error(problem)
        if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
            raise self.error("last row must be [0, 0, 0, 1]")
        return T

    def rotation(self) -> F64:
        R = self.matrix((3, 3))
        check_rigid(self, R)
        return R


def check_rigid(field: Field, R: F64) -> None:
    """Raise naming ``field`` unless R (3, 3) is a proper rotation."""
    if not is_rotation(R, _ROTATION_TOL):
        raise field.error("rotation part is not a proper rotation matrix (orthonormal, det +1)")


def _is_plain_matrix(v: Any) -> bool:
    return isinstance(v, Mapping) and "data" in v and ({"rows", "cols"} <= set(v) or "sizes" in v)


def _describe(v: Any) -> str:
    if v is None:
        return "nothing (null)"
    if isinstance(v, bool):
        return f"a boolean ({v})"
    if isinstance(v, str):
        shown = v if len(v) <= 40 else v[:37] + "..."
        return f"text {shown!r}"
    if isinstance(v, Mapping):
        return "a mapping"
    if isinstance(v, list | tuple):
        return f"a list of {len(v)}"
    if isinstance(v, TaggedMatrix | np.ndarray):
        return "a matrix"
    return type(v).__name__
