"""Disk cache of VPC lookup tables (DESIGN §5).

Key: sha256 of a canonical JSON of everything that determines a table (format version, the
fisheye model's name, size, lens limit and parameters, the VPC intrinsics and distortion, and
``R_cam_vpc`` rounded to 1e-12 so the same rotation computed two ways hits the same entry).

File ``<key>.lut``::

    b"ODFCLUT\\n"                      8-byte magic
    uint32 little-endian               length of the header
    header JSON (utf-8)                version, key, height, width, payload_bytes, payload_sha256,
                                       valid_fraction, build_ms, created, summary
    payload                            map_x f32 (H,W) | map_y f32 (H,W) | map1 i16 (H,W,2) |
                                       map2 u16 (H,W) | valid u8 (H,W)

A file with the wrong magic, version, key or shape, a short or long payload, or a payload whose
checksum differs is never trusted: it is logged, deleted and rebuilt. Files are written to a
temporary name in the cache directory, flushed and fsynced, then renamed over the final name, so
a crash mid-write never leaves a truncated ``.lut`` behind.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import struct
import tempfile
import time
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

LUT_FORMAT_VERSION = 1
CACHE_ENV = "RIG_CACHE_DIR"
MAGIC = b"ODFCLUT\n"
SUFFIX = ".lut"
_LEN = struct.Struct("<I")
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
            data = path.read_bytes()
        except FileNotFoundError:
            return None
        except OSError as err:
            log.warning("LUT cache file %s unreadable (%s); rebuilding", path, err)
            return None
        try:
            header, payload = _parse(data)
            if header.get("key") != key:
                raise _CorruptFile(f"holds key {str(header.get('key'))[:12]}…, expected {key[:12]}…")
            h, w = int(header["height"]), int(header["width"])
            if shape is not None and (h, w) != tuple(shape):
                raise _CorruptFile(f"holds a {w}x{h} table, expected {shape[1]}x{shape[0]}")
            return _decode(payload, h, w)
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
        payload = b"".join(p.tobytes() for p in parts)
        header = {
            "version": LUT_FORMAT_VERSION,
            "key": key,
            "height": h,
            "width": w,
            "payload_bytes": len(payload),
            "payload_sha256": hashlib.sha256(payload).hexdigest(),
            "valid_fraction": lut.valid_fraction,
            "build_ms": round(build_ms, 3),
            "created": time.time(),
            "summary": summary,
        }
        head = json.dumps(header, sort_keys=True).encode()
        self.directory.mkdir(parents=True, exist_ok=True)
        final = self.path(key)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{key[:16]}.", suffix=".tmp", dir=self.directory)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(MAGIC)
                f.write(_LEN.pack(len(head)))
                f.write(head)
                f.write(payload)
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
                data = path.read_bytes()
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


def _parse(data: bytes) -> tuple[dict[str, Any], memoryview]:
    """Check magic, header, version, payload length and checksum; (header, payload)."""
    if len(data) < len(MAGIC) + _LEN.size or not data.startswith(MAGIC):
        raise _CorruptFile("not a LUT file (bad magic)")
    (n,) = _LEN.unpack_from(data, len(MAGIC))
    start = len(MAGIC) + _LEN.size
    if start + n > len(data):
        raise _CorruptFile("header cut short")
    try:
        header = json.loads(data[start : start + n].decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise _CorruptFile(f"unreadable header ({err})") from err
    if not isinstance(header, dict):
        raise _CorruptFile("header is not a JSON object")
    if header.get("version") != LUT_FORMAT_VERSION:
        raise _CorruptFile(f"format version {header.get('version')!r}, expected {LUT_FORMAT_VERSION}")
    payload = memoryview(data)[start + n :]
    h, w = int(header["height"]), int(header["width"])
    expected = _payload_bytes(h, w)
    if len(payload) != expected or header.get("payload_bytes") != expected:
        raise _CorruptFile(f"payload is {len(payload)} bytes, expected {expected} (truncated?)")
    if hashlib.sha256(payload).hexdigest() != header.get("payload_sha256"):
        raise _CorruptFile("payload checksum mismatch")
    return header, payload


def _decode(payload: memoryview, h: int, w: int) -> Lut:
    arrays: dict[str, NDArray[Any]] = {}
    offset = 0
    for name, dt, shape in _payload_layout(h, w):
        count = int(np.prod(shape))
        # Copy: the table outlives the file buffer and must be writable/aligned for OpenCV.
        arrays[name] = np.frombuffer(payload, dtype=dt, count=count, offset=offset).reshape(shape).copy()
        offset += count * dt.itemsize
    valid = arrays["valid"].astype(bool)
    if not valid.any():
        raise _CorruptFile("table has no valid pixel")
    return Lut(
        arrays["map_x"].astype(np.float32, copy=False),
        arrays["map_y"].astype(np.float32, copy=False),
        arrays["map1"].astype(np.int16, copy=False),
        arrays["map2"].astype(np.uint16, copy=False),
        valid,
        float(np.count_nonzero(valid)) / valid.size,
    )
