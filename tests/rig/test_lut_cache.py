"""LUT disk cache: hits and misses, keys, corrupt/truncated/stale files, atomic writes, and
hostile entries (crafted headers, FIFOs, directories, symlinks, huge files, a read-only cache)."""

from __future__ import annotations

import contextlib
import errno
import logging
import math
import os
import re
import struct
import subprocess
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import rig.lut_cache as lut_cache
from calibration.atomic import TEMP_MARK
from calibration.geometry import rot_x, rot_y
from calibration.models import CameraModel, PinholeModel, create
from rig.lut_cache import MAGIC, LutCache, default_cache_dir, lut_key


def fisheye() -> CameraModel:
    return create(
        "kannala_brandt",
        320,
        240,
        fx=72.0,
        fy=71.8,
        cx=160.2,
        cy=119.6,
        k1=0.02,
        k2=-0.01,
        k3=0.003,
        k4=-0.0005,
        fov_deg=190.0,
    )


def rect_cam(**kw: float) -> PinholeModel:
    args: dict[str, float] = {"fx": 80.0, "fy": 80.0, "cx": 79.5, "cy": 59.5} | kw
    return PinholeModel(160, 120, **args)


R0 = rot_y(math.radians(40)) @ rot_x(math.radians(3))


def test_miss_then_hit_returns_the_same_table(tmp_path: Path) -> None:
    cache = LutCache(tmp_path)
    first = cache.get(fisheye(), R0, rect_cam())
    assert not first.hit and first.path.is_file() and first.build_ms > 0
    second = cache.get(fisheye(), R0, rect_cam())
    assert second.hit and second.key == first.key and second.path == first.path
    for name in ("map_x", "map_y", "map1", "map2", "valid"):
        a, b = getattr(first.lut, name), getattr(second.lut, name)
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), name
    assert second.lut.valid_fraction == first.lut.valid_fraction
    assert second.lut.map_x.flags.writeable and second.lut.map1.flags.c_contiguous


def test_key_changes_with_every_input_and_not_with_round_off() -> None:
    base = lut_key(fisheye(), R0, rect_cam())
    variants = {
        "fx": lut_key(fisheye().replace(fx=72.0001), R0, rect_cam()),
        "k4": lut_key(fisheye().replace(k4=-0.0005001), R0, rect_cam()),
        "size": lut_key(fisheye().replace(width=322), R0, rect_cam()),
        "fov": lut_key(fisheye().replace(fov_deg=180.0), R0, rect_cam()),
        "model": lut_key(
            create("equidistant", 320, 240, fx=72.0, fy=71.8, cx=160.2, cy=119.6, fov_deg=190.0),
            R0,
            rect_cam(),
        ),
        "vpc_fx": lut_key(fisheye(), R0, rect_cam(fx=80.5, fy=80.5)),
        "vpc_cx": lut_key(fisheye(), R0, rect_cam(cx=70.0)),
        "vpc_size": lut_key(fisheye(), R0, PinholeModel(162, 120, fx=80.0, fy=80.0, cx=79.5, cy=59.5)),
        "vpc_k1": lut_key(fisheye(), R0, rect_cam(k1=0.01)),
        "R": lut_key(fisheye(), R0 @ rot_y(1e-6), rect_cam()),
    }
    assert len(set(variants.values()) | {base}) == len(variants) + 1
    # The same rotation computed another way (round-off far below 1e-12) hits the same entry.
    assert lut_key(fisheye(), R0 @ rot_y(1e-16) + 1e-15, rect_cam()) == base
    assert lut_key(fisheye(), R0.copy(), rect_cam()) == base


def test_key_includes_the_format_version(monkeypatch: pytest.MonkeyPatch) -> None:
    base = lut_key(fisheye(), R0, rect_cam())
    monkeypatch.setattr(lut_cache, "LUT_FORMAT_VERSION", lut_cache.LUT_FORMAT_VERSION + 1)
    assert lut_key(fisheye(), R0, rect_cam()) != base


def _rebuilt_after(
    tmp_path: Path, damage: Callable[[Path], object], caplog: pytest.LogCaptureFixture
) -> None:
    cache = LutCache(tmp_path)
    first = cache.get(fisheye(), R0, rect_cam())
    damage(first.path)
    with caplog.at_level(logging.WARNING, logger="rig.lut_cache"):
        again = cache.get(fisheye(), R0, rect_cam())
    assert not again.hit, "a damaged file must not be trusted"
    assert any("rebuilding" in r.getMessage() and str(first.path) in r.getMessage() for r in caplog.records)
    assert np.array_equal(again.lut.map_x, first.lut.map_x)
    third = cache.get(fisheye(), R0, rect_cam())
    assert third.hit, "the rebuilt table was stored again"


def test_corrupt_payload_is_detected_and_rebuilt(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    def flip_byte(p: Path) -> None:
        data = bytearray(p.read_bytes())
        data[len(data) // 2] ^= 0x40
        p.write_bytes(bytes(data))

    _rebuilt_after(tmp_path, flip_byte, caplog)


def test_truncated_file_is_detected_and_rebuilt(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    _rebuilt_after(tmp_path, lambda p: p.write_bytes(p.read_bytes()[:-1000]), caplog)


def test_header_damage_and_garbage_are_detected(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    _rebuilt_after(tmp_path, lambda p: p.write_bytes(p.read_bytes()[:30]), caplog)
    _rebuilt_after(tmp_path, lambda p: p.write_bytes(b"not a table at all"), caplog)
    _rebuilt_after(tmp_path, lambda p: p.write_bytes(MAGIC + b"\xff\xff\x00\x00{"), caplog)


def test_stale_file_under_the_wrong_key_is_rebuilt(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    cache = LutCache(tmp_path)
    other = cache.get(fisheye(), R0 @ rot_y(0.05), rect_cam())
    key = lut_key(fisheye(), R0, rect_cam())
    cache.path(key).write_bytes(other.path.read_bytes())  # a valid file, but of another table
    with caplog.at_level(logging.WARNING, logger="rig.lut_cache"):
        got = cache.get(fisheye(), R0, rect_cam())
    assert not got.hit
    assert not np.array_equal(got.lut.map_x, other.lut.map_x)
    assert any("stale" in r.getMessage() for r in caplog.records)


def test_older_format_version_is_rebuilt(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cache = LutCache(tmp_path)
    first = cache.get(fisheye(), R0, rect_cam())
    # Pretend this build reads a newer format: the same key's file is now of an old version.
    monkeypatch.setattr(lut_cache, "LUT_FORMAT_VERSION", lut_cache.LUT_FORMAT_VERSION + 1)
    assert cache.load(first.key) is None
    assert not first.path.exists(), "the outdated file was removed"


def test_write_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cache = LutCache(tmp_path)
    good = cache.get(fisheye(), R0, rect_cam())
    before = good.path.read_bytes()

    def crash(fd: int) -> None:
        raise OSError(28, "No space left on device")

    # A write that dies before the rename leaves the old file intact and no temporary behind.
    monkeypatch.setattr(lut_cache.os, "fsync", crash)
    with pytest.raises(OSError):
        cache.store(good.key, good.lut)
    assert good.path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [good.path.name]
    # Through get(), an unwritable cache costs a rebuild but never the table.
    good.path.unlink()
    got = cache.get(fisheye(), R0, rect_cam())
    assert not got.hit and np.array_equal(got.lut.map_x, good.lut.map_x)
    assert list(tmp_path.iterdir()) == []


def test_directory_from_argument_env_and_default(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RIG_CACHE_DIR", str(tmp_path / "env"))
    assert default_cache_dir() == tmp_path / "env"
    assert LutCache().directory == tmp_path / "env"
    assert LutCache(tmp_path / "arg").directory == tmp_path / "arg"
    monkeypatch.delenv("RIG_CACHE_DIR")
    assert default_cache_dir().parts[-2:] == ("odfc-rig", "lut")


def test_entries_and_clear(tmp_path: Path) -> None:
    cache = LutCache(tmp_path / "c")
    assert cache.entries() == [] and cache.clear() == 0
    a = cache.get(fisheye(), R0, rect_cam())
    b = cache.get(fisheye(), R0 @ rot_y(0.1), rect_cam())
    (tmp_path / "c" / ("0" * 64 + ".lut")).write_bytes(b"junk")
    entries = {e.path.name: e for e in cache.entries()}
    assert set(entries) == {a.path.name, b.path.name, "0" * 64 + ".lut"}
    assert entries[a.path.name].ok and entries[a.path.name].size_bytes == a.path.stat().st_size
    assert entries[a.path.name].valid_fraction == pytest.approx(a.lut.valid_fraction)
    assert "kannala_brandt 320x240 -> vpc 160x120" in entries[a.path.name].summary
    assert not entries["0" * 64 + ".lut"].ok and entries["0" * 64 + ".lut"].problem
    (tmp_path / "c" / f".{a.path.name}{TEMP_MARK}1-2-3").write_bytes(b"half a table")  # a killed writer's
    assert cache.clear() == 3
    assert cache.entries() == []
    assert os.listdir(tmp_path / "c") == []


# ----- hostile entries: never trusted, never blocking, one warning ------------------------------
def _rewrite_header(path: Path, edit: Callable[[str], str]) -> None:
    """Rewrite the header text of a cache file (the payload stays as it was)."""
    data = path.read_bytes()
    (n,) = struct.unpack_from("<I", data, len(MAGIC))
    start = len(MAGIC) + 4
    head = edit(data[start : start + n].decode()).encode()
    path.write_bytes(MAGIC + struct.pack("<I", len(head)) + head + data[start + n :])


def _field(name: str, text: str) -> Callable[[str], str]:
    """Replace the value of header field ``name`` by the JSON ``text`` (NaN, Infinity allowed)."""
    return lambda head: re.sub(rf'"{name}": [^,}}]+', f'"{name}": {text}', head)


# Each of these crashed start-up ("internal error") or was read as a valid table before.
CRAFTED_HEADERS = {
    "infinite height": _field("height", "Infinity"),
    "NaN width": _field("width", "NaN"),
    "1e400 height": _field("height", "1e400"),
    "fractional height": _field("height", "120.5"),
    "height as text": _field("height", '"120"'),
    "height true": _field("height", "true"),
    "negative size": lambda h: _field("width", "-1")(_field("height", "-1")(h)),
    "absurd size": lambda h: _field("width", "1000000000")(_field("height", "1000000000")(h)),
    "payload_bytes as float": _field("payload_bytes", "288000.0"),
    "crc beyond 32 bits": _field("payload_crc32", "18446744073709551616"),
    "NaN valid fraction": _field("valid_fraction", "NaN"),
    "version true": _field("version", "true"),
    "key a number": _field("key", "7"),
    "header a list": lambda h: "[1, 2]",
    "deeply nested": lambda h: "[" * 100_000 + "]" * 100_000,
}


@pytest.mark.parametrize("edit", CRAFTED_HEADERS.values(), ids=list(CRAFTED_HEADERS))
def test_crafted_headers_are_refused_and_rebuilt(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, edit: Callable[[str], str]
) -> None:
    _rebuilt_after(tmp_path, lambda p: _rewrite_header(p, edit), caplog)


def test_a_header_length_beyond_the_limit_is_refused_unread(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # A header that claims 4 GiB (in a file that is really that long, sparse): nothing is read.
    def huge_header(p: Path) -> None:
        with open(p, "r+b") as f:
            f.seek(len(MAGIC))
            f.write(struct.pack("<I", 0xFFFFFFF0))
            f.truncate(2**32 + 64)

    _rebuilt_after(tmp_path, huge_header, caplog)


def test_a_huge_file_is_refused_without_reading_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Before: the whole file was read into memory (3 GiB here, sparse) before any check.
    cache = LutCache(tmp_path)
    first = cache.get(fisheye(), R0, rect_cam())
    with open(first.path, "r+b") as f:
        f.truncate(3 * 2**30)
    reads: list[int] = []
    real_empty = np.empty

    def counting_empty(shape: Any, *args: Any, **kw: Any) -> Any:
        reads.append(int(np.prod(shape)))
        return real_empty(shape, *args, **kw)

    monkeypatch.setattr(lut_cache.np, "empty", counting_empty)
    again = LutCache(tmp_path).get(fisheye(), R0, rect_cam())
    assert not again.hit and np.array_equal(again.lut.map_x, first.lut.map_x)
    assert max(reads) < 2**20, "no buffer for the file's claimed size was allocated"
    assert first.path.stat().st_size < 2**20, "and stored again at its own size"


def _get_within(cache: LutCache, seconds: float) -> lut_cache.CachedLut:
    """``cache.get`` in a thread; fails the test (instead of hanging it) if it blocks."""
    out: list[lut_cache.CachedLut] = []
    t = threading.Thread(target=lambda: out.append(cache.get(fisheye(), R0, rect_cam())), daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), f"the cache lookup blocked for more than {seconds} s"
    assert out
    return out[0]


NOT_FILES: dict[str, Callable[[Path], object]] = {
    "FIFO": os.mkfifo,  # before: start-up hung forever in open()
    "directory": lambda p: p.mkdir(),
    "symlink to /dev/zero": lambda p: p.symlink_to("/dev/zero"),
    "dangling symlink": lambda p: p.symlink_to(p.with_name("nowhere")),
}


@pytest.mark.parametrize("make", NOT_FILES.values(), ids=list(NOT_FILES))
def test_an_entry_that_is_not_a_file_is_ignored_and_never_blocks(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, make: Callable[[Path], object]
) -> None:
    good = LutCache(tmp_path / "good").get(fisheye(), R0, rect_cam())
    cache = LutCache(tmp_path / "c")
    cache.directory.mkdir()
    entry = cache.path(good.key)
    make(entry)
    try:
        with caplog.at_level(logging.WARNING, logger="rig.lut_cache"):
            got = _get_within(cache, 10.0)
            again = _get_within(cache, 10.0)
        assert not got.hit and np.array_equal(got.lut.map1, good.lut.map1)
        warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
        assert len(warnings) == 1 and str(entry) in warnings[0], warnings
        assert ("directory" in warnings[0]) == entry.is_dir()
        listed = cache.entries()  # `rig lut show` lists it without blocking either
        assert [e.path for e in listed] == [entry] and (listed[0].ok == again.hit)
    finally:
        if entry.is_fifo():  # release a reader still blocked on the FIFO (the old code's hang)
            os.close(os.open(entry, os.O_WRONLY | os.O_NONBLOCK))


@contextlib.contextmanager
def _read_only(directory: Path) -> Iterator[str]:
    """``directory`` made read-only for the duration: a read-only tmpfs where one can be mounted
    (root), else its permissions (a non-root user), else (root without mount rights) writes
    refused by an injected EROFS. Yields which one was used."""
    if os.geteuid() != 0:
        directory.chmod(0o555)
        try:
            yield "chmod 555"
        finally:
            directory.chmod(0o755)
        return
    if _mount_read_only_copy(directory):
        try:
            yield "read-only tmpfs"
        finally:
            subprocess.run(["umount", str(directory)], check=True)
        return
    with pytest.MonkeyPatch.context() as mp:

        def refuse(*args: Any, **kw: Any) -> Any:
            raise OSError(errno.EROFS, "Read-only file system")

        mp.setattr(lut_cache, "atomic_file", refuse)
        mp.setattr(Path, "unlink", refuse)
        yield "injected EROFS"


def _mount_read_only_copy(directory: Path) -> bool:
    """Mount a tmpfs over ``directory`` holding a copy of its files, read-only; False where
    mounting is not allowed."""
    saved = {p.name: p.read_bytes() for p in directory.iterdir()}
    mount = ["mount", "-t", "tmpfs", "-o", "size=4m", "rig-test-ro", str(directory)]
    if subprocess.run(mount, capture_output=True).returncode != 0:
        return False
    for name, data in saved.items():
        (directory / name).write_bytes(data)
    subprocess.run(["mount", "-o", "remount,ro", str(directory)], check=True)
    return True


def test_a_corrupt_file_in_a_read_only_cache_is_rebuilt_in_memory_with_one_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    directory = tmp_path / "ro"
    good = LutCache(directory).get(fisheye(), R0, rect_cam())
    data = bytearray(good.path.read_bytes())
    data[len(data) // 2] ^= 0x40
    good.path.write_bytes(bytes(data))
    with _read_only(directory) as how:
        cache = LutCache(directory)
        with caplog.at_level(logging.WARNING, logger="rig.lut_cache"):
            got = cache.get(fisheye(), R0, rect_cam())
            again = cache.get(fisheye(), R0, rect_cam())
        print(f"read-only cache directory by {how}")
        assert not got.hit and not again.hit
        assert np.array_equal(got.lut.map1, good.lut.map1) and np.array_equal(again.lut.map2, good.lut.map2)
        warnings = [r.getMessage() for r in caplog.records]
        assert len(warnings) == 1, warnings
        assert "checksum" in warnings[0] and "in memory" in warnings[0] and "not writable" in warnings[0]
        assert good.path.read_bytes() == bytes(data), "the damaged file is still there, untouched"


def test_clear_leaves_what_is_not_a_cache_file(tmp_path: Path) -> None:
    cache = LutCache(tmp_path)
    a = cache.get(fisheye(), R0, rect_cam())
    (tmp_path / ("1" * 64 + ".lut")).mkdir()
    os.mkfifo(tmp_path / ("2" * 64 + ".lut"))
    assert cache.clear() == 1 and not a.path.exists()
    assert sorted(p.name[0] for p in tmp_path.iterdir()) == ["1", "2"]
