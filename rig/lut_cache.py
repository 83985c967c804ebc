"""Disk cache of VPC lookup tables (docs/design.md, "LUT cache").

Key: sha256 of a canonical JSON of everything that determines a table (format version, the
fisheye model's name, size, lens limit and parameters, the VPC intrinsics and distortion, and
``R_cam_vpc`` rounded to 1e-12 so the same rotation computed two ways hits the same entry).

File ``<key>.lut``::

    b"ODFCLUT\\n"                      8-byte magic
    uint32 little-endian               length of the header
    header JSON (utf-8), space-padded  version, key, height, width, payload_bytes, payload_crc32,
                                       valid_fraction, build_ms, created, summary; padded so the
                                       payload starts at a multiple of 64 bytes
    payload                            map_x f32 (H,W) | map_y f32 (H,W) | map1 i16 (H,W,2) |
                                       map2 u16 (H,W) | valid u8 (H,W)

A file with the wrong magic, version, key or shape, a short or long payload, or a payload whose
CRC-32 differs is never trusted: it is logged, deleted and rebuilt. Files are written to a
temporary name in the cache directory, flushed and fsynced, then renamed over the final name, so
a crash mid-write never leaves a truncated ``.lut`` behind.

Loading is one read into an aligned buffer, a CRC-32 over the payload (zlib: ~6 GB/s, against
~1.8 GB/s for sha256; it catches every burst error up to 32 bits and all but 2⁻³² of random
damage — enough for disk corruption, which is what it guards against) and array views into that
buffer: no copies (~1 ms for a 640×480 table).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import struct
import tempfile
import time
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import platformdirs
from numpy.typing import ArrayLike, NDArray

from calibration.models import CameraModel, PinholeModel
from rig.lut import Lut, build_vpc_lut

__all__ = [
    "CACHE_ENV",
    "LUT_FORMAT_VERSION",
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
# R_cam_vpc is rounded to this many decimals in the key: 1e-12 rad moves a pixel by ~1e-9 px.
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


def lut_key(model: CameraModel, R_cam_vpc: ArrayLike, vpc_camera: PinholeModel) -> str:
    """sha256 hex of the canonical description of one table (see module doc)."""
    doc = {
        "format": LUT_FORMAT_VERSION,
        "fisheye": model.to_dict(),
        "vpc": vpc_camera.to_dict(),
        "R_cam_vpc": _canonical_rotation(R_cam_vpc),
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


class _CorruptFile(Exception):
    pass


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


def _summary(model: CameraModel, vpc_camera: PinholeModel) -> str:
    return f"{model.name} {model.width}x{model.height} -> vpc {vpc_camera.width}x{vpc_camera.height}"


class LutCache:
    """Directory of ``<key>.lut`` files. ``directory`` defaults to :func:`default_cache_dir`."""

    def __init__(self, directory: str | Path | None = None) -> None:
        self.directory = Path(directory).expanduser() if directory is not None else default_cache_dir()

    def path(self, key: str) -> Path:
        return self.directory / f"{key}{SUFFIX}"

    # ----- lookup ------------------------------------------------------------------------------
    def get(self, model: CameraModel, R_cam_vpc: ArrayLike, vpc_camera: PinholeModel) -> CachedLut:
        """The table from the cache, or built (and stored) when missing, stale or corrupt."""
        key = lut_key(model, R_cam_vpc, vpc_camera)
        path = self.path(key)
        lut = self.load(key, (vpc_camera.height, vpc_camera.width))
        if lut is not None:
            return CachedLut(lut, key, path, True, 0.0)
        t0 = time.perf_counter()
        lut = build_vpc_lut(model, R_cam_vpc, vpc_camera)
        build_ms = (time.perf_counter() - t0) * 1e3
        try:
            self.store(key, lut, build_ms=build_ms, summary=_summary(model, vpc_camera))
        except OSError as err:
            # A read-only or full cache costs a rebuild next time; it must not stop the pipeline.
            log.warning("LUT cache %s not writable (%s); using the table uncached", self.directory, err)
        return CachedLut(lut, key, path, False, build_ms)

    def load(self, key: str, shape: tuple[int, int] | None = None) -> Lut | None:
        """The table stored under ``key``; None when absent. A file that fails any check is
        logged, deleted and reported as absent so the caller rebuilds it."""
        path = self.path(key)
        try:
            data = _read_file(path)
        except FileNotFoundError:
            return None
        except OSError as err:
            log.warning("LUT cache file %s unreadable (%s); rebuilding", path, err)
            return None
        try:
            header, offset = _parse(data)
            if header.get("key") != key:
                raise _CorruptFile(f"holds key {str(header.get('key'))[:12]}…, expected {key[:12]}…")
            h, w = int(header["height"]), int(header["width"])
            if shape is not None and (h, w) != tuple(shape):
                raise _CorruptFile(f"holds a {w}x{h} table, expected {shape[1]}x{shape[0]}")
            return _decode(data, offset, h, w)
        except (_CorruptFile, KeyError, TypeError, ValueError) as err:
            log.warning("LUT cache file %s is corrupt or stale (%s); rebuilding", path, err)
            path.unlink(missing_ok=True)
            return None

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
        head = json.dumps(header, sort_keys=True).encode()
        head += b" " * (-(len(MAGIC) + _LEN.size + len(head)) % _ALIGN)
        self.directory.mkdir(parents=True, exist_ok=True)
        final = self.path(key)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{key[:16]}.", suffix=".tmp", dir=self.directory)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(MAGIC)
                f.write(_LEN.pack(len(head)))
                f.write(head)
                for part in parts:
                    f.write(part.data.cast("B"))
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp_name, final)
        except BaseException:
            Path(tmp_name).unlink(missing_ok=True)
            raise
        return final

    # ----- listing -----------------------------------------------------------------------------
    def entries(self) -> list[CacheEntry]:
        """Every ``.lut`` file, newest first, each checked (``ok``/``problem``)."""
        if not self.directory.is_dir():
            return []
        out: list[CacheEntry] = []
        now = time.time()
        for path in self.directory.glob(f"*{SUFFIX}"):
            try:
                stat = path.stat()
                data = _read_file(path)
            except OSError as err:
                out.append(CacheEntry(path, 0, 0.0, path.stem, "", None, False, str(err)))
                continue
            try:
                header, _ = _parse(data)
                ok, problem = header.get("key") == path.stem, ""
                if not ok:
                    problem = "key does not match the file name"
                vf = header.get("valid_fraction")
                out.append(
                    CacheEntry(
                        path,
                        stat.st_size,
                        now - stat.st_mtime,
                        path.stem,
                        str(header.get("summary", "")),
                        float(vf) if isinstance(vf, int | float) else None,
                        ok,
                        problem,
                    )
                )
            except (_CorruptFile, KeyError, TypeError, ValueError) as err:
                out.append(
                    CacheEntry(path, stat.st_size, now - stat.st_mtime, path.stem, "", None, False, str(err))
                )
        out.sort(key=lambda e: e.age_s)
        return out

    def clear(self) -> int:
        """Delete every cache file (and stray temporary files); returns how many tables."""
        if not self.directory.is_dir():
            return 0
        n = 0
        for path in self.directory.glob(f"*{SUFFIX}"):
            path.unlink(missing_ok=True)
            n += 1
        for path in self.directory.glob(".*.tmp"):
            path.unlink(missing_ok=True)
        return n


def _read_file(path: Path) -> NDArray[np.uint8]:
    """The whole file in one fresh (aligned, writable) buffer."""
    with open(path, "rb", buffering=0) as f:
        size = os.fstat(f.fileno()).st_size
        buf = np.empty(size, dtype=np.uint8)
        view = buf.data
        got = 0
        while got < size:
            n = f.readinto(view[got:])
            if not n:
                break  # the file shrank while we read: the length check reports it
            got += n
    return buf[:got]


def _parse(data: NDArray[np.uint8]) -> tuple[dict[str, Any], int]:
    """Check magic, header, version, payload length and checksum; (header, payload offset)."""
    raw = data.data
    start = len(MAGIC) + _LEN.size
    if len(raw) < start or bytes(raw[: len(MAGIC)]) != MAGIC:
        raise _CorruptFile("not a LUT file (bad magic)")
    (n,) = _LEN.unpack_from(raw, len(MAGIC))
    if start + n > len(raw):
        raise _CorruptFile("header cut short")
    try:
        header = json.loads(bytes(raw[start : start + n]).decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise _CorruptFile(f"unreadable header ({err})") from err
    if not isinstance(header, dict):
        raise _CorruptFile("header is not a JSON object")
    if header.get("version") != LUT_FORMAT_VERSION:
        raise _CorruptFile(f"format version {header.get('version')!r}, expected {LUT_FORMAT_VERSION}")
    offset = start + n
    h, w = int(header["height"]), int(header["width"])
    expected = _payload_bytes(h, w)
    if len(raw) - offset != expected or header.get("payload_bytes") != expected:
        raise _CorruptFile(f"payload is {len(raw) - offset} bytes, expected {expected} (truncated?)")
    if zlib.crc32(raw[offset:]) != header.get("payload_crc32"):
        raise _CorruptFile("payload checksum mismatch")
    return header, offset


def _decode(data: NDArray[np.uint8], offset: int, h: int, w: int) -> Lut:
    """Array views into ``data`` (the buffer outlives nothing: the views keep it alive)."""
    arrays: dict[str, NDArray[Any]] = {}
    for name, dt, shape in _payload_layout(h, w):
        nbytes = dt.itemsize * int(np.prod(shape))
        arrays[name] = data[offset : offset + nbytes].view(dt).reshape(shape)
        offset += nbytes
    valid = arrays["valid"] != 0
    count = int(np.count_nonzero(valid))
    if count == 0:
        raise _CorruptFile("table has no valid pixel")
    return Lut(
        arrays["map_x"].view(np.float32),
        arrays["map_y"].view(np.float32),
        arrays["map1"].view(np.int16),
        arrays["map2"].view(np.uint16),
        valid,
        count / valid.size,
    )
