"""What ``/health`` reports about the computer: CPU temperature, load, free disk for recordings.

Read from the kernel's interfaces each time (cheap: a few small sysfs files); every value is
None where the board does not expose it, never a guess.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

__all__ = ["HostInfo", "cpu_temperature_c", "free_disk_bytes", "host_info"]

THERMAL_ROOT = Path("/sys/class/thermal")
# Zone types that measure the CPU/SoC (x86 package, Raspberry Pi, Jetson, Rockchip ...).
_CPU_ZONE_HINTS = ("cpu", "x86_pkg", "soc", "coretemp", "k10temp", "package")


@dataclass(frozen=True)
class HostInfo:
    cpu_temp_c: float | None
    load_avg: tuple[float, float, float] | None
    cpu_count: int | None
    disk_free_bytes: int | None
    disk_path: str


def cpu_temperature_c(root: Path = THERMAL_ROOT) -> float | None:
    """Hottest CPU-like thermal zone in °C (any zone if none is labelled CPU); None if absent."""
    cpu: list[float] = []
    other: list[float] = []
    for zone in sorted(root.glob("thermal_zone*")):
        try:
            milli = int((zone / "temp").read_text().strip())
        except (OSError, ValueError):
            continue
        try:
            kind = (zone / "type").read_text().strip().lower()
        except OSError:
            kind = ""
        (cpu if any(h in kind for h in _CPU_ZONE_HINTS) else other).append(milli / 1000.0)
    values = cpu or other
    return max(values) if values else None


def free_disk_bytes(path: Path) -> int | None:
    """Free bytes on the file system that holds ``path`` (or its nearest existing parent)."""
    p = path.expanduser()
    for candidate in (p, *p.parents):
        if candidate.exists():
            try:
                return int(shutil.disk_usage(candidate).free)
            except OSError:
                return None
    return None


def host_info(recordings_dir: Path, thermal_root: Path = THERMAL_ROOT) -> HostInfo:
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    return HostInfo(
        cpu_temp_c=cpu_temperature_c(thermal_root),
        load_avg=None if load is None else (float(load[0]), float(load[1]), float(load[2])),
        cpu_count=os.cpu_count(),
        disk_free_bytes=free_disk_bytes(recordings_dir),
        disk_path=str(recordings_dir),
    )
