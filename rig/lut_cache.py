"""Disk cache of VPC lookup tables (docs/design.md, "LUT cache").

Key: sha256 of a canonical JSON of everything that determines a table (format version, the
fisheye model's name, size, lens limit and parameters, the VPC intrinsics and distortion, and
``R_cam_rect`` rounded to 1e-12 so the same rotation computed two ways hits the same entry).

File ``<key>.lut``::

    b"ODFCLUT\\n"                      8-byte magic
    uint32 little-endian               length of the header
    header JSON (utf-8), space-padded  version, key, height, width, payload_bytes, payload_crc32,
                                       valid_fraction, build_ms, created, summary; padded so the
                                       payload starts at a multiple of 64 bytes
    payload                            map_x f32 (H,W) | map_y f32 (H,W) | map1 i16 (H,W,2) |
                                       map2 u16 (H,W) | valid u8 (H,W)

The cache is never trusted and never blocks. An entry is opened without following a symlink
and without blocking (``O_NOFOLLOW | O_NONBLOCK``: a FIFO in its place does not hang start-up)
and used only if ``fstat`` says it is a regular file whose size is exactly what its header
claims; the header is at most :data:`MAX_HEADER_BYTES`, strict JSON (no NaN or Infinity), and
every field has its type and range checked (an image side is an integer in 1..:data:`MAX_SIDE`)
before anything is allocated, so no file can make the reader allocate or read more than the
table it names. A file with the wrong magic, version, key or shape, a short or long payload, or
a payload whose CRC-32 differs is not used: it is deleted when it can be and the table is
rebuilt, in memory if the cache cannot be written (a read-only directory), with one warning per
key. Anything else in the entry's place (a directory, a FIFO, a device, a symlink) is left alone
and rebuilt around the same way. What the payload holds cannot harm the remap: OpenCV masks the
fixed-point fractions (``map2``) to its table and maps coordinates outside the image to the
constant border.

Files are written through :func:`calibration.atomic.atomic_file` (a temporary name in the cache
directory, flushed and fsynced, then renamed over the final name), so a crash mid-write never
leaves a truncated ``.lut`` behind.

Loading is one read of the payload into an aligned buffer, a CRC-32 over the payload (zlib: ~6 GB/s, against
~1.8 GB/s for sha256; it catches every burst error up to 32 bits and all but 2⁻³² of random
damage — enough for disk corruption, which is what it guards against) and array views into that
buffer: no copies (~1 ms for a 640×480 table).
"""

from __future__ import annotations

import errno
import hashlib
import json
import logging
import math
import os
import stat
import struct
import time
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import platformdirs
from numpy.typing import ArrayLike, NDArray

from calibration.atomic import atomic_file, is_temporary
from calibration.models import CameraModel, PinholeModel
from rig.errors import LutError
from rig.lut import Lut, build_rectified_lut

__all__ = [
    "CACHE_ENV",
    "LUT_FORMAT_VERSION",
    "MAX_HEADER_BYTES",
    "MAX_SIDE",
    "CacheEntry",
    "CachedLut",
    "LutCache",
    "default_cache_dir",
    "lut_key",
]

log = logging.getLogger(__name__)

LUT_FORMAT_VERSION = 2
CACHE_ENV = "RIG_CACHE_DIR"
MAGIC = b"ODFCLUT\n"
SUFFIX = ".lut"
_LEN = struct.Struct("<I")
# The payload starts at a multiple of this (array views stay aligned for numpy and OpenCV).
_ALIGN = 64
#: Longest header a cache file may have (a real one is ~400 bytes).
MAX_HEADER_BYTES = 64 * 1024
#: Largest table side a cache file may hold: the largest VPC side rig.rectified.RectifiedPairConfig accepts.
MAX_SIDE = 8192
# R_cam_rect is rounded to this many decimals in the key: 1e-12 rad moves a pixel by ~1e-9 px.
_R_DECIMALS = 12


def default_cache_dir() -> Path:
    """``$RIG_CACHE_DIR`` if set, else the user cache dir + ``odfc-rig/lut``."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    return Path(platformdirs.user_cache_dir("odfc-rig")) / "lut"


def _canonical_rotation(R: ArrayLike) -> list[list[float]]:
    Rr = np.round(np.asarray(R, dtype=np.float64), _R_DECIMALS) + 0.0  # + 0.0 folds -0.0 into 0.0
    return [[float(x) for x in row] for row in Rr]


def lut_key(model: CameraModel, R_cam_rect: ArrayLike, rect_camera: CameraModel) -> str:
    """sha256 hex of the canonical description of one table (see module doc)."""
    doc = {
        "format": LUT_FORMAT_VERSION,
        "fisheye": model.to_dict(),
        "vpc": rect_camera.to_dict(),
        "R_cam_vpc": _canonical_rotation(R_cam_rect),
    }
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass(frozen=True)
class CachedLut:
    """A table with where it came from: ``hit`` is True when it was read from the cache."""

    lut: Lut
    key: str
    path: Path
    hit: bool
    build_ms: float


@dataclass(frozen=True)
class CacheEntry:
    """One file of the cache as listed by ``rig lut show``."""

    path: Path
    size_bytes: int
    age_s: float
    key: str
    summary: str
    valid_fraction: float | None
    ok: bool
    problem: str = ""


class _Unusable(Exception):
    """A cache entry that is not used. ``ours``: it is a regular file (a damaged or stale
    table) that may be deleted; anything else in its place is left alone."""

    def __init__(self, problem: str, *, ours: bool = True) -> None:
        super().__init__(problem)
        self.ours = ours


@dataclass(frozen=True)
class _Header:
    """The checked header of one cache file."""

    key: str
    height: int
    width: int
    payload_bytes: int
    payload_crc32: int
    valid_fraction: float
    summary: str


def _payload_layout(h: int, w: int) -> list[tuple[str, np.dtype[Any], tuple[int, ...]]]:
    return [
        ("map_x", np.dtype("<f4"), (h, w)),
        ("map_y", np.dtype("<f4"), (h, w)),
        ("map1", np.dtype("<i2"), (h, w, 2)),
        ("map2", np.dtype("<u2"), (h, w)),
        ("valid", np.dtype("u1"), (h, w)),
    ]


def _payload_bytes(h: int, w: int) -> int:
    return sum(dt.itemsize * int(np.prod(shape)) for _, dt, shape in _payload_layout(h, w))


def _summary(model: CameraModel, rect_camera: CameraModel) -> str:
    kind = "" if isinstance(rect_camera, PinholeModel) else f" {rect_camera.name}"
    return f"{model.name} {model.width}x{model.height} -> vpc {rect_camera.width}x{rect_camera.height}{kind}"


class LutCache:
    """Directory of ``<key>.lut`` files. ``directory`` defaults to :func:`default_cache_dir`.

    An entry that cannot be used, or a table that cannot be stored, is reported by one warning
    per key and cache (see the module doc); the table is used all the same."""

    def __init__(self, directory: str | Path | None = None) -> None:
        self.directory = Path(directory).expanduser() if directory is not None else default_cache_dir()
        self._warned: set[str] = set()

    def path(self, key: str) -> Path:
        return self.directory / f"{key}{SUFFIX}"

    # ----- lookup ------------------------------------------------------------------------------
    def get(self, model: CameraModel, R_cam_rect: ArrayLike, rect_camera: CameraModel) -> CachedLut:
        """The table from the cache, or built (and stored) when missing, stale or corrupt."""
        key = lut_key(model, R_cam_rect, rect_camera)
        path = self.path(key)
        lut, problem = self._load(key, (rect_camera.height, rect_camera.width))
        if lut is not None:
            return CachedLut(lut, key, path, True, 0.0)
        t0 = time.perf_counter()
        lut = build_rectified_lut(model, R_cam_rect, rect_camera)
        build_ms = (time.perf_counter() - t0) * 1e3
        try:
            self.store(key, lut, build_ms=build_ms, summary=_summary(model, rect_camera))
        except OSError as err:
            # A read-only or full cache costs a rebuild next time; it must not stop the pipeline.
            where = f"LUT cache file {path} {problem}" if problem else f"LUT cache {self.directory}"
            why = err.strerror or err
            self._warn_once(key, f"{where}; rebuilding the table in memory (cache not writable: {why})")
        else:
            if problem:
                self._warn_once(key, f"LUT cache file {path} {problem}; rebuilding the table (stored again)")
        return CachedLut(lut, key, path, False, build_ms)

    def load(self, key: str, shape: tuple[int, int] | None = None) -> Lut | None:
        """The table stored under ``key``; None when absent or unusable (then logged once per
        key, and a damaged file deleted where it can be, so the caller rebuilds it)."""
        lut, problem = self._load(key, shape)
        if problem:
            self._warn_once(key, f"LUT cache file {self.path(key)} {problem}; rebuilding the table")
        return lut

    def _load(self, key: str, shape: tuple[int, int] | None) -> tuple[Lut | None, str | None]:
        """(table, None) from a good entry, (None, None) when there is none, (None, what is
        wrong) when the entry is unusable (a damaged one deleted where that is possible)."""
        path = self.path(key)
        try:
            header, payload = _read_entry(path, key, shape)
            return _decode(payload, header.height, header.width), None
        except FileNotFoundError:
            return None, None
        except _Unusable as err:
            problem = str(err)
            if err.ours:
                try:
                    path.unlink(missing_ok=True)
                except OSError as unlink_err:
                    problem += f" (left in place: {unlink_err.strerror or unlink_err})"
            return None, problem
        except OSError as err:
            return None, f"is unreadable ({err.strerror or err})"

    def discard(self, key: str) -> None:
        """Delete the table stored under ``key`` (best effort: a damaged or foreign entry is
        reported by the next lookup)."""
        path = self.path(key)
        try:
            if _removable(path):
                path.unlink(missing_ok=True)
        except OSError as err:
            log.debug("could not remove %s: %s", path, err)

    def _warn_once(self, key: str, message: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            log.warning("%s", message)

    # ----- writing -----------------------------------------------------------------------------
    def store(self, key: str, lut: Lut, *, build_ms: float = 0.0, summary: str = "") -> Path:
        """Write ``lut`` under ``key`` atomically (temporary file, fsync, rename)."""
        h, w = lut.shape
        parts = [
            np.ascontiguousarray(lut.map_x, dtype="<f4"),
            np.ascontiguousarray(lut.map_y, dtype="<f4"),
            np.ascontiguousarray(lut.map1, dtype="<i2"),
            np.ascontiguousarray(lut.map2, dtype="<u2"),
            np.ascontiguousarray(lut.valid, dtype="u1"),
        ]
        crc = 0
        for part in parts:
            crc = zlib.crc32(part.data.cast("B"), crc)
        header = {
            "version": LUT_FORMAT_VERSION,
            "key": key,
            "height": h,
            "width": w,
            "payload_bytes": sum(p.nbytes for p in parts),
            "payload_crc32": crc,
            "valid_fraction": lut.valid_fraction,
            "build_ms": round(build_ms, 3),
            "created": time.time(),
            "summary": summary,
        }
        head = json.dumps(header, sort_keys=True, allow_nan=False).encode()
        head += b" " * (-(len(MAGIC) + _LEN.size + len(head)) % _ALIGN)
        self.directory.mkdir(parents=True, exist_ok=True)
        final = self.path(key)
        with atomic_file(final) as f:
            f.write(MAGIC)
            f.write(_LEN.pack(len(head)))
            f.write(head)
            for part in parts:
                f.write(part.data.cast("B"))
        return final

    # ----- listing -----------------------------------------------------------------------------
    def entries(self) -> list[CacheEntry]:
        """Every ``.lut`` entry, newest first, each checked (``ok``/``problem``) the way a
        lookup checks it (nothing is deleted)."""
        if not self.directory.is_dir():
            return []
        out: list[CacheEntry] = []
        now = time.time()
        for path in self.directory.glob(f"*{SUFFIX}"):
            try:
                st = path.lstat()
            except OSError:
                continue  # gone since the listing
            size, age = st.st_size, now - st.st_mtime
            try:
                header, _ = _read_entry(path, None, None)
            except (_Unusable, OSError) as err:
                problem = str(err) if isinstance(err, _Unusable) else f"is unreadable ({err.strerror or err})"
                out.append(CacheEntry(path, size, age, path.stem, "", None, False, problem))
                continue
            ok = header.key == path.stem
            problem = "" if ok else "key does not match the file name"
            out.append(
                CacheEntry(path, size, age, path.stem, header.summary, header.valid_fraction, ok, problem)
            )
        out.sort(key=lambda e: e.age_s)
        return out

    def clear(self) -> int:
        """Delete every cache file (and stray temporary files); returns how many tables.
        Entries that are not files (a directory, a FIFO) are not the cache's and stay;
        LutError when the directory does not allow deleting."""
        if not self.directory.is_dir():
            return 0
        n = 0
        try:
            for path in self.directory.glob(f"*{SUFFIX}"):
                if _removable(path):
                    path.unlink(missing_ok=True)
                    n += 1
            for path in self.directory.iterdir():
                if is_temporary(path.name) and _removable(path):
                    path.unlink(missing_ok=True)
        except OSError as err:
            raise LutError(f"{self.directory}: cannot clear the LUT cache ({err.strerror or err})") from err
        return n


def _removable(path: Path) -> bool:
    try:
        mode = path.lstat().st_mode
    except FileNotFoundError:
        return False
    return stat.S_ISREG(mode) or stat.S_ISLNK(mode)


# ----- reading -----------------------------------------------------------------------------------
_FILE_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def _open_regular(path: Path) -> tuple[int, int]:
    """(fd, size) of ``path`` opened for reading if it is a regular file; never blocks (a FIFO
    opens at once with O_NONBLOCK) and never follows a symlink. _Unusable otherwise."""
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise _Unusable("is a symlink, not a cache file", ours=False) from err
        if err.errno in (errno.EISDIR, errno.ENXIO):  # a directory; a socket or writer-less FIFO
            raise _Unusable("is not a regular file", ours=False) from err
        raise
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            kind = next((name for test, name in _FILE_KINDS if test(st.st_mode)), "not a regular file")
            raise _Unusable(f"is {kind}, not a cache file", ours=False)
    except BaseException:
        os.close(fd)
        raise
    return fd, st.st_size


def _read_into(f: Any, n: int) -> NDArray[np.uint8]:
    """Exactly ``n`` bytes from ``f`` into a fresh (aligned, writable) buffer."""
    buf = np.empty(n, dtype=np.uint8)
    view, got = buf.data, 0
    while got < n:
        k = f.readinto(view[got:])
        if not k:
            raise _Unusable(f"was cut short while read ({got} of {n} bytes)")
        got += k
    return buf


def _read_entry(
    path: Path, key: str | None, shape: tuple[int, int] | None
) -> tuple[_Header, NDArray[np.uint8]]:
    """The checked header and the payload (checksum verified) of one cache file. Reads no more
    than the header allows (``MAX_HEADER_BYTES``) and the payload it describes, and that only
    once the file's size matches; _Unusable (or OSError) otherwise."""
    fd, size = _open_regular(path)
    with open(fd, "rb", buffering=0, closefd=True) as f:
        start = len(MAGIC) + _LEN.size
        prefix = f.read(start) if size >= start else b""
        if len(prefix) < start or prefix[: len(MAGIC)] != MAGIC:
            raise _Unusable("is corrupt or stale (not a LUT file: bad magic)")
        (n,) = _LEN.unpack_from(prefix, len(MAGIC))
        if n > MAX_HEADER_BYTES or start + n > size:
            raise _Unusable(f"is corrupt or stale (header of {n} bytes in a file of {size})")
        header = _check_header(bytes(_read_into(f, n)), key, shape)
        expected = start + n + header.payload_bytes
        if size != expected:
            raise _Unusable(f"is corrupt or stale (file is {size} bytes, its header implies {expected})")
        payload = _read_into(f, header.payload_bytes)
    if zlib.crc32(payload.data) != header.payload_crc32:
        raise _Unusable("is corrupt or stale (payload checksum mismatch)")
    return header, payload


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number JSON allows")


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:39] + "…"


def _int_field(doc: dict[str, Any], name: str, lo: int, hi: int) -> int:
    v = doc.get(name)
    if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
        raise _Unusable(
            f"is corrupt or stale (header field {name!r} is {_shown(v)}, not an integer in {lo}..{hi})"
        )
    return v


def _number_field(doc: dict[str, Any], name: str, lo: float, hi: float) -> float:
    v = doc.get(name)
    if not isinstance(v, int | float) or isinstance(v, bool) or not (math.isfinite(v) and lo <= v <= hi):
        what = f"header field {name!r} is {_shown(v)}, not a number in [{lo:g}, {hi:g}]"
        raise _Unusable(f"is corrupt or stale ({what})")
    return float(v)


def _check_header(raw: bytes, key: str | None, shape: tuple[int, int] | None) -> _Header:
    """Every header field checked for its type and range (see the module doc)."""
    try:
        doc = json.loads(raw.decode("utf-8"), parse_constant=_refuse_constant)
    except (UnicodeDecodeError, ValueError, RecursionError) as err:
        raise _Unusable(f"is corrupt or stale (unreadable header: {str(err)[:80]})") from err
    if not isinstance(doc, dict):
        raise _Unusable("is corrupt or stale (header is not a JSON object)")
    version = doc.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or version != LUT_FORMAT_VERSION:
        raise _Unusable(
            f"is corrupt or stale (format version {_shown(version)}, expected {LUT_FORMAT_VERSION})"
        )
    found = doc.get("key")
    if not isinstance(found, str) or (key is not None and found != key):
        raise _Unusable(f"is corrupt or stale (holds key {str(found)[:12]}…, expected {(key or '')[:12]}…)")
    h = _int_field(doc, "height", 1, MAX_SIDE)
    w = _int_field(doc, "width", 1, MAX_SIDE)
    if shape is not None and (h, w) != tuple(shape):
        raise _Unusable(f"is corrupt or stale (holds a {w}x{h} table, expected {shape[1]}x{shape[0]})")
    payload = _payload_bytes(h, w)
    _int_field(doc, "payload_bytes", payload, payload)  # exactly what the size implies
    crc = _int_field(doc, "payload_crc32", 0, 2**32 - 1)
    valid_fraction = _number_field(doc, "valid_fraction", 0.0, 1.0)
    _number_field(doc, "build_ms", 0.0, 1e9)
    _number_field(doc, "created", 0.0, 1e11)
    summary = doc.get("summary")
    if not isinstance(summary, str):
        raise _Unusable("is corrupt or stale (header field 'summary' is not text)")
    return _Header(found, h, w, payload, crc, valid_fraction, summary[:200])


def _decode(payload: NDArray[np.uint8], h: int, w: int) -> Lut:
    """Array views into ``payload`` (no copies: the views keep the buffer alive)."""
    arrays: dict[str, NDArray[Any]] = {}
    offset = 0
    for name, dt, shape in _payload_layout(h, w):
        nbytes = dt.itemsize * int(np.prod(shape))
        arrays[name] = payload[offset : offset + nbytes].view(dt).reshape(shape)
        offset += nbytes
    valid = arrays["valid"] != 0
    count = int(np.count_nonzero(valid))
    if count == 0:
        raise _Unusable("is corrupt or stale (table has no valid pixel)")
    return Lut(
        arrays["map_x"].view(np.float32),
        arrays["map_y"].view(np.float32),
        arrays["map1"].view(np.int16),
        arrays["map2"].view(np.uint16),
        valid,
        count / valid.size,
    )
