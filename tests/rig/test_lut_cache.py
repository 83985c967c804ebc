"""LUT disk cache: hits and misses, keys, corrupt/truncated/stale files, atomic writes."""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import rig.lut_cache as lut_cache
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


def vpc_cam(**kw: float) -> PinholeModel:
    args: dict[str, float] = {"fx": 80.0, "fy": 80.0, "cx": 79.5, "cy": 59.5} | kw
    return PinholeModel(160, 120, **args)


R0 = rot_y(math.radians(40)) @ rot_x(math.radians(3))


def test_miss_then_hit_returns_the_same_table(tmp_path: Path) -> None:
    cache = LutCache(tmp_path)
    first = cache.get(fisheye(), R0, vpc_cam())
    assert not first.hit and first.path.is_file() and first.build_ms > 0
    second = cache.get(fisheye(), R0, vpc_cam())
    assert second.hit and second.key == first.key and second.path == first.path
    for name in ("map_x", "map_y", "map1", "map2", "valid"):
        a, b = getattr(first.lut, name), getattr(second.lut, name)
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), name
    assert second.lut.valid_fraction == first.lut.valid_fraction
    assert second.lut.map_x.flags.writeable and second.lut.map1.flags.c_contiguous


def test_key_changes_with_every_input_and_not_with_round_off() -> None:
    base = lut_key(fisheye(), R0, vpc_cam())
    variants = {
        "fx": lut_key(fisheye().replace(fx=72.0001), R0, vpc_cam()),
        "k4": lut_key(fisheye().replace(k4=-0.0005001), R0, vpc_cam()),
        "size": lut_key(fisheye().replace(width=322), R0, vpc_cam()),
        "fov": lut_key(fisheye().replace(fov_deg=180.0), R0, vpc_cam()),
        "model": lut_key(
            create("equidistant", 320, 240, fx=72.0, fy=71.8, cx=160.2, cy=119.6, fov_deg=190.0),
            R0,
            vpc_cam(),
        ),
        "vpc_fx": lut_key(fisheye(), R0, vpc_cam(fx=80.5, fy=80.5)),
        "vpc_cx": lut_key(fisheye(), R0, vpc_cam(cx=70.0)),
        "vpc_size": lut_key(fisheye(), R0, PinholeModel(162, 120, fx=80.0, fy=80.0, cx=79.5, cy=59.5)),
        "vpc_k1": lut_key(fisheye(), R0, vpc_cam(k1=0.01)),
        "R": lut_key(fisheye(), R0 @ rot_y(1e-6), vpc_cam()),
    }
    assert len(set(variants.values()) | {base}) == len(variants) + 1
    # The same rotation computed another way (round-off far below 1e-12) hits the same entry.
    assert lut_key(fisheye(), R0 @ rot_y(1e-16) + 1e-15, vpc_cam()) == base
    assert lut_key(fisheye(), R0.copy(), vpc_cam()) == base


def test_key_includes_the_format_version(monkeypatch: pytest.MonkeyPatch) -> None:
    base = lut_key(fisheye(), R0, vpc_cam())
    monkeypatch.setattr(lut_cache, "LUT_FORMAT_VERSION", lut_cache.LUT_FORMAT_VERSION + 1)
    assert lut_key(fisheye(), R0, vpc_cam()) != base


def _rebuilt_after(
    tmp_path: Path, damage: Callable[[Path], object], caplog: pytest.LogCaptureFixture
) -> None:
    cache = LutCache(tmp_path)
    first = cache.get(fisheye(), R0, vpc_cam())
    damage(first.path)
    with caplog.at_level(logging.WARNING, logger="rig.lut_cache"):
        again = cache.get(fisheye(), R0, vpc_cam())
    assert not again.hit, "a damaged file must not be trusted"
    assert any("rebuilding" in r.getMessage() and str(first.path) in r.getMessage() for r in caplog.records)
    assert np.array_equal(again.lut.map_x, first.lut.map_x)
    third = cache.get(fisheye(), R0, vpc_cam())
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
    other = cache.get(fisheye(), R0 @ rot_y(0.05), vpc_cam())
    key = lut_key(fisheye(), R0, vpc_cam())
    cache.path(key).write_bytes(other.path.read_bytes())  # a valid file, but of another table
    with caplog.at_level(logging.WARNING, logger="rig.lut_cache"):
        got = cache.get(fisheye(), R0, vpc_cam())
    assert not got.hit
    assert not np.array_equal(got.lut.map_x, other.lut.map_x)
    assert any("stale" in r.getMessage() for r in caplog.records)


def test_older_format_version_is_rebuilt(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cache = LutCache(tmp_path)
    first = cache.get(fisheye(), R0, vpc_cam())
    # Pretend this build reads a newer format: the same key's file is now of an old version.
    monkeypatch.setattr(lut_cache, "LUT_FORMAT_VERSION", lut_cache.LUT_FORMAT_VERSION + 1)
    assert cache.load(first.key) is None
    assert not first.path.exists(), "the outdated file was removed"


def test_write_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cache = LutCache(tmp_path)
    good = cache.get(fisheye(), R0, vpc_cam())
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
    got = cache.get(fisheye(), R0, vpc_cam())
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
    a = cache.get(fisheye(), R0, vpc_cam())
    b = cache.get(fisheye(), R0 @ rot_y(0.1), vpc_cam())
    (tmp_path / "c" / ("0" * 64 + ".lut")).write_bytes(b"junk")
    entries = {e.path.name: e for e in cache.entries()}
    assert set(entries) == {a.path.name, b.path.name, "0" * 64 + ".lut"}
    assert entries[a.path.name].ok and entries[a.path.name].size_bytes == a.path.stat().st_size
    assert entries[a.path.name].valid_fraction == pytest.approx(a.lut.valid_fraction)
    assert "kannala_brandt 320x240 -> vpc 160x120" in entries[a.path.name].summary
    assert not entries["0" * 64 + ".lut"].ok and entries["0" * 64 + ".lut"].problem
    assert cache.clear() == 3
    assert cache.entries() == []
    assert os.listdir(tmp_path / "c") == []
