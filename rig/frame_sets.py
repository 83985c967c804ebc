"""One row of a recording's ``frames.csv``: a synchronised set of one frame per camera.

``frames.csv`` has the column ``seq``, then ``<name>_ts_ns`` for every camera, then
``<name>_file`` for every camera, in the order ``recording.json`` lists the cameras. The
two-camera recording (cameras ``left``, ``right``) is the case N = 2, byte for byte today's
``seq,left_ts_ns,right_ts_ns,left_file,right_file`` (:data:`FRAMES_HEADER`).

Camera names become folder names and column names, so they are checked
(:func:`camera_name_problem`): letters, digits, ``_``, ``.`` and ``-``, starting with a letter,
digit or ``_``, at most 64 characters.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from rig.errors import RecordingError

__all__ = [
    "FRAMES_HEADER",
    "FrameSetRecord",
    "PairRecord",
    "camera_name_problem",
    "frames_header",
    "spoken_list",
]

_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}")


def frames_header(cameras: Sequence[str]) -> tuple[str, ...]:
    """The ``frames.csv`` header of a recording of ``cameras`` (see the module doc)."""
    return ("seq", *(f"{c}_ts_ns" for c in cameras), *(f"{c}_file" for c in cameras))


#: The header of a two-camera recording.
FRAMES_HEADER = frames_header(("left", "right"))


def camera_name_problem(name: object) -> str | None:
    """What is wrong with ``name`` as a recorded camera's name, or None."""
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        return (
            f"camera name {name!r} must be 1-64 letters, digits, '_', '.' or '-' (first a letter, "
            "digit or '_')"
        )
    return None


def spoken_list(items: Sequence[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} and {items[-1]}"


@dataclass(frozen=True)
class FrameSetRecord:
    """One row of ``frames.csv``: ``seq``, and per camera (in ``cameras`` order) its capture
    time ``stamps`` and its frame ``files`` (relative to the recording)."""

    seq: int
    cameras: tuple[str, ...]
    stamps: tuple[int, ...]
    files: tuple[str, ...]

    @classmethod
    def of(cls, seq: int, stamps: Mapping[str, int], files: Mapping[str, str]) -> FrameSetRecord:
        """From per-camera mappings (in ``stamps``' order)."""
        cameras = tuple(stamps)
        return cls(seq, cameras, tuple(int(stamps[c]) for c in cameras), tuple(files[c] for c in cameras))

    @classmethod
    def pair(
        cls,
        seq: int,
        left_ts_ns: int,
        right_ts_ns: int,
        left_file: str,
        right_file: str,
        names: tuple[str, str] = ("left", "right"),
    ) -> FrameSetRecord:
        """A two-camera row."""
        return cls(seq, names, (int(left_ts_ns), int(right_ts_ns)), (left_file, right_file))

    def _index(self, camera: str) -> int:
        try:
            return self.cameras.index(camera)
        except ValueError:
            raise RecordingError(
                f"unknown camera {camera!r} (the recording has {', '.join(map(repr, self.cameras))})"
            ) from None

    def file(self, camera: str) -> str:
        return self.files[self._index(camera)]

    def ts_ns(self, camera: str) -> int:
        return self.stamps[self._index(camera)]

    @property
    def first_ts_ns(self) -> int:
        """The first camera's capture time: the set's (a pair's is its left frame's)."""
        return self.stamps[0]

    @property
    def left_ts_ns(self) -> int:
        return self.ts_ns("left")

    @property
    def right_ts_ns(self) -> int:
        return self.ts_ns("right")

    @property
    def left_file(self) -> str:
        return self.file("left")

    @property
    def right_file(self) -> str:
        return self.file("right")

    def csv_row(self) -> str:
        """The row as ``frames.csv`` holds it, newline included."""
        return ",".join((str(self.seq), *(str(t) for t in self.stamps), *self.files)) + "\n"

    @classmethod
    def parse(cls, fields: Sequence[str], cameras: Sequence[str]) -> FrameSetRecord:
        """The row of ``fields`` (split CSV) of a recording of ``cameras``; RecordingError (no
        file or line: the caller names them) for a malformed one."""
        n = len(cameras)
        header = frames_header(cameras)
        if len(fields) != len(header):
            raise RecordingError(f"expected {len(header)} fields, got {len(fields)}")
        try:
            seq, *stamps = (int(f) for f in fields[: n + 1])
        except ValueError:
            raise RecordingError(f"{spoken_list(header[: n + 1])} must be integers") from None
        if seq < 0:
            raise RecordingError(f"seq must be >= 0, got {seq}")
        files = tuple(fields[n + 1 :])
        if not all(files):
            raise RecordingError(f"{spoken_list(header[n + 1 :])} must not be empty")
        if any("\x00" in f for f in files):
            raise RecordingError(f"{spoken_list(header[n + 1 :])} must not contain NUL characters")
        return cls(seq, tuple(cameras), tuple(stamps), files)


#: Today's name of a row (a two-camera recording's pair).
PairRecord = FrameSetRecord
