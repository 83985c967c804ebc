"""Recording directories (docs/design.md, "Recording directory"): written by ``rig record`` and
the renderer, read by the file cameras and ``rig process``.

Layout::

    recording.json   {"version": 1, "cameras": ["left", "right"], ...}   (N ≥ 1 names, in order)
    frames.csv       seq,left_ts_ns,right_ts_ns,left_file,right_file   (append-only; rig.frame_sets)
    left/NNNNNN.jpg  frames as the camera delivered them (MJPEG byte-exact; .png when rendered)
    right/NNNNNN.jpg
    calibration.yaml (optional) and ground_truth/ (renderer only)

A recording of N cameras has a folder per camera and the columns ``seq``, ``<name>_ts_ns`` per
camera, ``<name>_file`` per camera (:func:`rig.frame_sets.frames_header`); the two-camera
recording is its case N = 2, byte for byte.

Crash safety: every frame file of a set is written and flushed before its row is appended to
``frames.csv`` in one write and flushed, so a ``kill -9`` loses at most the set in flight and
every indexed row points at complete files.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import io
import json
import logging
import os
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.atomic import write_atomic as _atomic_write
from rig.errors import DiskFullError, RecordingError, ResourceExhausted
from rig.frame_sets import FRAMES_HEADER, FrameSetRecord, PairRecord, camera_name_problem, frames_header
from rig.image_size import size_problem
from rig.stored_frame import StoredFrame

__all__ = [
    "FRAMES_HEADER",
    "RECORDING_VERSION",
    "FrameSetRecord",
    "PairRecord",
    "PairWriter",
    "Recording",
    "RecordingWriter",
    "StoredFrame",
    "frames_header",
]

log = logging.getLogger(__name__)

RECORDING_VERSION = 1
_NO_SPACE = {errno.ENOSPC, errno.EDQUOT}


class Recording:
    """A recording directory opened for reading; validates ``recording.json`` and ``frames.csv``.

    A final ``frames.csv`` line cut short by a crash (no newline, unparsable) is skipped with a
    warning; any other malformed line is an error naming the file and line.
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise RecordingError(f"{self.root}: not a recording directory (does not exist)")
        self.meta = self._read_meta()
        self.cameras: list[str] = _camera_list(self.meta.get("cameras"), self.root / "recording.json")
        self.truncated_tail = False
        #: The rows of ``frames.csv``: one synchronised frame set each (a pair's for two cameras).
        self.pairs: list[FrameSetRecord] = self._read_index()

    # ----- reading -----------------------------------------------------------------------------
    def _read_meta(self) -> dict[str, Any]:
        path = self.root / "recording.json"
        try:
            meta = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise RecordingError(f"{path}: missing (not a recording directory)") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
            raise RecordingError(f"{path}: unreadable JSON ({err})") from err
        if not isinstance(meta, dict):
            raise RecordingError(f"{path}: must hold a JSON object")
        version = meta.get("version")
        if version != RECORDING_VERSION:
            raise RecordingError(
                f"{path}: field 'version' is {version!r}; this build reads version {RECORDING_VERSION}"
            )
        return meta

    def _read_index(self) -> list[FrameSetRecord]:
        path = self.root / "frames.csv"
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise RecordingError(f"{path}: missing") from None
        except (OSError, UnicodeDecodeError) as err:
            raise RecordingError(f"{path}: unreadable ({err})") from err
        lines = text.split("\n")
        complete_tail = text.endswith("\n")
        if complete_tail:
            lines = lines[:-1]
        header = frames_header(self.cameras)
        if not lines or tuple(lines[0].strip().split(",")) != header:
            raise RecordingError(f"{path}: line 1: header must be {','.join(header)}")
        pairs: list[FrameSetRecord] = []
        seen: set[int] = set()
        for lineno, line in enumerate(lines[1:], start=2):
            last = lineno == len(lines)
            if not line.strip():
                continue
            try:
                pair = self._parse_row(line)
            except RecordingError as err:
                if last and not complete_tail:
                    log.warning("%s: skipping line %d cut short by a crash", path, lineno)
                    self.truncated_tail = True
                    break
                raise RecordingError(f"{path}: line {lineno}: {err}") from None
            if pair.seq in seen:
                raise RecordingError(f"{path}: line {lineno}: duplicate seq {pair.seq}")
            seen.add(pair.seq)
            pairs.append(pair)
        return pairs

    def _parse_row(self, line: str) -> FrameSetRecord:
        return FrameSetRecord.parse(next(csv.reader([line])), self.cameras)

    def __len__(self) -> int:
        return len(self.pairs)

    def __iter__(self) -> Iterator[FrameSetRecord]:
        return iter(self.pairs)

    def path(self, relative: str) -> Path:
        """Absolute path of a file named in the index; refuses paths leaving the recording."""
        if "\x00" in relative:  # the OS cannot name it; pathlib would raise ValueError
            raise RecordingError(f"{self.root / 'frames.csv'}: file {relative!r} is not a valid file name")
        root = self.root.resolve()
        p = (root / relative).resolve()
        if not p.is_relative_to(root):
            raise RecordingError(f"{self.root / 'frames.csv'}: file {relative!r} lies outside the recording")
        return p

    def read_bytes(self, pair: FrameSetRecord, camera: str) -> bytes:
        """The frame file exactly as stored (MJPEG bytes for camera recordings); RecordingError
        if it is missing or unreadable, ResourceExhausted if the process has no file descriptor
        left to open it (the file is fine: not a broken frame)."""
        p = self.path(pair.file(camera))
        try:
            return p.read_bytes()
        except OSError as err:
            if err.errno in (errno.EMFILE, errno.ENFILE):
                raise ResourceExhausted(f"{p}: cannot open the {camera} frame: {fd_exhaustion(err)}") from err
            raise RecordingError(
                f"{p}: {camera} frame of seq {pair.seq} unreadable ({err.strerror})"
            ) from err

    def read_frame(self, pair: FrameSetRecord, camera: str) -> StoredFrame:
        """The frame file as a :class:`StoredFrame` (format from its extension, bytes as stored);
        RecordingError naming the file for a missing file or an unsupported file type."""
        path = self.path(pair.file(camera))
        lower = path.name.lower()
        if lower.endswith((".jpg", ".jpeg")):
            fmt = "jpeg"
        elif lower.endswith(".png"):
            fmt = "png"
        else:
            raise RecordingError(f"{path}: unsupported frame file type (expected .jpg or .png)")
        return StoredFrame(fmt, raw=self.read_bytes(pair, camera), source=str(path))

    def read_image(
        self, pair: FrameSetRecord, camera: str, flags: int = cv2.IMREAD_UNCHANGED
    ) -> NDArray[Any]:
        """Decoded frame; RecordingError naming the file and seq if it is missing or corrupt (or
        its header declares a frame larger than any camera's)."""
        data = self.read_bytes(pair, camera)
        fmt = "png" if pair.file(camera).lower().endswith(".png") else "jpeg"
        ok = bool(data) and size_problem(data, fmt, None) is None
        img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags) if ok else None
        if img is None:
            raise RecordingError(
                f"{self.path(pair.file(camera))}: {camera} frame of seq {pair.seq} is not a readable image"
            )
        return img

    @property
    def calibration_path(self) -> Path | None:
        """``calibration.yaml`` when the recording carries one (renderer output)."""
        p = self.root / "calibration.yaml"
        return p if p.is_file() else None

    @property
    def ground_truth_dir(self) -> Path:
        return self.root / "ground_truth"


class PairWriter(Protocol):
    """What a recorder writes pairs into: a recording directory (:class:`RecordingWriter`) or an
    MCAP file (``rig.ros.mcap_export.McapRecordingWriter``)."""

    root: Path
    count: int

    def write_set(
        self, seq: int, stamps: Sequence[int], frames: Sequence[bytes], ext: str = ".jpg"
    ) -> object:
        """One encoded frame per camera, stored byte-exact."""

    def write_set_images(self, seq: int, stamps: Sequence[int], images: Sequence[NDArray[Any]]) -> object:
        """One decoded frame per camera, stored losslessly."""

    def write_pair(
        self, seq: int, left_ts_ns: int, right_ts_ns: int, left: bytes, right: bytes, ext: str = ".jpg"
    ) -> object:
        """Two encoded frames (a two-camera recording), stored byte-exact."""

    def write_images(
        self, seq: int, left_ts_ns: int, right_ts_ns: int, left: NDArray[Any], right: NDArray[Any]
    ) -> object:
        """Two decoded frames, stored losslessly."""

    def close(self) -> None:
        """Finish what was written."""


class RecordingWriter:
    """Writes a recording of ``cameras`` set by set (pair by pair for two); see the module
    docstring for the crash-safety order.

    ``fsync=True`` also forces data to the device (survives power loss, costs latency);
    flushing alone already survives a killed process.
    """

    def __init__(
        self,
        root: str | Path,
        *,
        meta: Mapping[str, Any] | None = None,
        cameras: Sequence[str] = ("left", "right"),
        fsync: bool = False,
    ) -> None:
        self.root = Path(root)
        self.cameras = _camera_list(list(cameras), self.root / "recording.json")
        self.fsync = fsync
        self.count = 0
        self._meta_bytes = 0  # recording.json as written here
        self._frame_bytes = 0
        self._index_size = 0
        index = self.root / "frames.csv"
        if index.exists():
            raise RecordingError(f"{self.root}: already holds a recording (frames.csv exists)")
        try:
            for cam in self.cameras:
                (self.root / cam).mkdir(parents=True, exist_ok=True)
            doc = {"version": RECORDING_VERSION, "cameras": self.cameras, **(meta or {})}
            doc["version"], doc["cameras"] = RECORDING_VERSION, self.cameras
            meta_bytes = json.dumps(doc, indent=2).encode() + b"\n"
            _atomic_write(self.root / "recording.json", meta_bytes)
            self._meta_bytes = len(meta_bytes)
            # Unbuffered: each row reaches the kernel in one write() the moment it is appended.
            self._index: io.FileIO | None = open(index, "ab", buffering=0)  # noqa: SIM115
            self._append_index((",".join(frames_header(self.cameras)) + "\n").encode())
        except OSError as err:
            raise self._translate(err, self.root) from err
        self._seqs: set[int] = set()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def write_set(
        self, seq: int, stamps: Sequence[int], frames: Sequence[bytes], ext: str = ".jpg"
    ) -> FrameSetRecord:
        """Store one encoded frame per camera (in :attr:`cameras` order) byte-exact, with its
        capture time, then index them. Returns the indexed row."""
        if self._index is None:
            raise RecordingError(f"{self.root}: recording already closed")
        if len(stamps) != len(self.cameras) or len(frames) != len(self.cameras):
            raise RecordingError(
                f"{self.root}: a set of this recording holds {len(self.cameras)} frames "
                f"({', '.join(self.cameras)}), got {len(frames)}"
            )
        if seq in self._seqs or seq < 0:
            # Writing it would overwrite the frame files of an indexed set.
            raise RecordingError(f"{self.root}: seq {seq} already written or negative")
        record = FrameSetRecord(
            seq,
            tuple(self.cameras),
            tuple(int(t) for t in stamps),
            tuple(f"{cam}/{seq:06d}{ext}" for cam in self.cameras),
        )
        written: list[Path] = []
        try:
            for rel, data in zip(record.files, frames, strict=True):
                p = self.root / rel
                with open(p, "wb") as f:
                    written.append(p)
                    f.write(data)
                    f.flush()
                    if self.fsync:
                        os.fsync(f.fileno())
            self._append_index(record.csv_row().encode())
            if self.fsync:
                os.fsync(self._index.fileno())
        except OSError as err:
            # An unindexed partial set is removed so the directory holds only complete sets.
            for p in written:
                p.unlink(missing_ok=True)
            raise self._translate(err, self.root) from err
        self._seqs.add(seq)
        self.count += 1
        self._frame_bytes += sum(len(data) for data in frames)
        return record

    def write_set_images(
        self, seq: int, stamps: Sequence[int], images: Sequence[NDArray[Any]]
    ) -> FrameSetRecord:
        """Store one decoded image per camera losslessly as PNG (rendered frames)."""
        enc = []
        for img in images:
            ok, buf = cv2.imencode(".png", img)
            if not ok:
                raise RecordingError(f"{self.root}: could not encode frame {seq} as PNG")
            enc.append(buf.tobytes())
        return self.write_set(seq, stamps, enc, ext=".png")

    def write_pair(
        self,
        seq: int,
        left_ts_ns: int,
        right_ts_ns: int,
        left: bytes,
        right: bytes,
        ext: str = ".jpg",
    ) -> FrameSetRecord:
        """Two encoded frames (a two-camera recording) byte-exact: :meth:`write_set`."""
        return self.write_set(seq, (left_ts_ns, right_ts_ns), (left, right), ext)

    def write_images(
        self, seq: int, left_ts_ns: int, right_ts_ns: int, left: NDArray[Any], right: NDArray[Any]
    ) -> FrameSetRecord:
        """Two decoded images losslessly as PNG: :meth:`write_set_images`."""
        return self.write_set_images(seq, (left_ts_ns, right_ts_ns), (left, right))

    @property
    def data_bytes(self) -> int:
        """Bytes of the frame files and ``frames.csv`` written so far, counted as they are
        written (a recording of an hour has a hundred thousand files, too many to stat whenever
        someone asks)."""
        return self._frame_bytes + self._index_size

    @property
    def bytes_written(self) -> int:
        """:attr:`data_bytes` and ``recording.json``."""
        return self.data_bytes + self._meta_bytes

    def _append_index(self, data: bytes) -> None:
        """Append one row; on failure cut the file back so no partial row stays behind."""
        assert self._index is not None
        start = self._index_size
        try:
            view = memoryview(data)
            while view:
                n = self._index.write(view)
                if not n:
                    raise OSError(errno.EIO, "short write")
                view = view[n:]
        except OSError:
            with contextlib.suppress(OSError):
                os.ftruncate(self._index.fileno(), start)
            raise
        self._index_size = start + len(data)

    def close(self) -> None:
        if self._index is not None:
            try:
                self._index.close()
            except OSError as err:
                raise self._translate(err, self.root) from err
            finally:
                self._index = None

    @staticmethod
    def _translate(err: OSError, root: Path) -> RecordingError:
        if err.errno in _NO_SPACE:
            return DiskFullError(f"{root}: disk full; recording stopped, everything indexed so far is intact")
        if err.errno in (errno.EMFILE, errno.ENFILE):
            return RecordingError(f"{root}: cannot write recording: {fd_exhaustion(err)}")
        return RecordingError(f"{root}: cannot write recording ({err.strerror or err})")


def _camera_list(cams: Any, where: Path) -> list[str]:
    """The ``cameras`` of a recording: a non-empty list of distinct valid names
    (:func:`rig.frame_sets.camera_name_problem`); RecordingError naming ``where`` and the field."""
    if not isinstance(cams, list) or not cams or not all(isinstance(c, str) for c in cams):
        raise RecordingError(f"{where}: field 'cameras' must be a list of names")
    for c in cams:
        problem = camera_name_problem(c)
        if problem is not None:
            raise RecordingError(f"{where}: field 'cameras': {problem}")
    if len(set(cams)) != len(cams):
        raise RecordingError(f"{where}: field 'cameras' names a camera twice ({', '.join(cams)})")
    return list(cams)


def fd_exhaustion(err: OSError) -> str:
    """What an EMFILE/ENFILE means, with the limit to raise."""
    if err.errno == errno.ENFILE:
        return "the system has run out of file descriptors (ENFILE)"
    import resource  # POSIX only

    soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    return f"the process has run out of file descriptors (EMFILE: all {soft} of ulimit -n are open)"
