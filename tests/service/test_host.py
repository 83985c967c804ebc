"""Host figures for /health: CPU temperature from a sysfs-shaped tree, load, free disk."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from service.host import cpu_temperature_c, free_disk_bytes, host_info


def zone(root: Path, n: int, kind: str, milli: str) -> None:
    d = root / f"thermal_zone{n}"
    d.mkdir(parents=True)
    (d / "type").write_text(kind + "\n")
    (d / "temp").write_text(milli + "\n")


def test_cpu_zone_preferred_over_others(tmp_path: Path) -> None:
    zone(tmp_path, 0, "acpitz", "80000")
    zone(tmp_path, 1, "cpu-thermal", "51234")
    zone(tmp_path, 2, "x86_pkg_temp", "49000")
    assert cpu_temperature_c(tmp_path) == 51.234


def test_any_zone_when_none_is_cpu_and_broken_zones_skipped(tmp_path: Path) -> None:
    zone(tmp_path, 0, "acpitz", "41500")
    zone(tmp_path, 1, "gpu", "garbage")
    assert cpu_temperature_c(tmp_path) == 41.5


def test_no_thermal_zones_is_none(tmp_path: Path) -> None:
    assert cpu_temperature_c(tmp_path) is None
    assert cpu_temperature_c(tmp_path / "missing") is None


def test_free_disk_of_nearest_existing_parent(tmp_path: Path) -> None:
    expected = shutil.disk_usage(tmp_path).free
    got = free_disk_bytes(tmp_path / "not" / "yet" / "created")
    assert got is not None and abs(got - expected) < 64 * 1024 * 1024  # other writers may run


def test_host_info_load_average(tmp_path: Path) -> None:
    info = host_info(tmp_path, thermal_root=tmp_path / "none")
    assert info.cpu_temp_c is None
    assert info.load_avg is not None and len(info.load_avg) == 3 and all(x >= 0 for x in info.load_avg)
    assert info.cpu_count == os.cpu_count()
    assert info.disk_path == str(tmp_path)
