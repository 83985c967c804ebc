"""What every benchmark shares: the machine description, statistics, argument parsing, JSON
output and the cache directory for generated inputs.

Benchmarks are not tests (docs/performance.md): each prints figures and ratios measured in one run against
the bare OpenCV calls doing the same work. The machine is part of every result: CPU model, cores,
load average at the start and the end (other work on a shared machine skews everything), and the
OpenCV/numpy versions.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import platformdirs
import yaml
from rich.console import Console
from rich.table import Table

__all__ = [
    "BENCH_CACHE_ENV",
    "add_common_arguments",
    "add_stereo_argument",
    "bench_cache_dir",
    "console",
    "finish",
    "machine_info",
    "median",
    "percentile",
    "print_machine",
    "stereo_overrides",
    "summary",
    "time_calls",
]

BENCH_CACHE_ENV = "RIG_BENCH_CACHE"
# Wide enough for the tables when the output is a file or a pipe (rich assumes 80 columns).
console = Console(highlight=False, width=None if sys.stdout.isatty() else 180)


def bench_cache_dir() -> Path:
    """Where generated inputs (recordings) are kept between runs: ``$RIG_BENCH_CACHE`` or the user
    cache dir + ``odfc-rig/bench``."""
    env = os.environ.get(BENCH_CACHE_ENV)
    if env:
        return Path(env).expanduser()
    return Path(platformdirs.user_cache_dir("odfc-rig")) / "bench"


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_info() -> dict[str, Any]:
    """CPU model, logical CPUs (and those this process may use), load average, versions."""
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        usable = os.cpu_count() or 0
    return {
        "cpu": _cpu_model(),
        "cpus": os.cpu_count(),
        "cpus_usable": usable,
        "load_avg": [round(x, 2) for x in os.getloadavg()],
        "python": platform.python_version(),
        "numpy": np.__version__,
        "opencv": cv2.__version__,
        "opencv_threads": cv2.getNumThreads(),
        "platform": platform.platform(),
    }


def print_machine(info: dict[str, Any], title: str) -> None:
    console.print(f"[bold]{title}[/bold]")
    console.print(
        f"machine: {info['cpu']}, {info['cpus']} logical CPUs ({info['cpus_usable']} usable), "
        f"load average {' / '.join(f'{x:.2f}' for x in info['load_avg'])} (1/5/15 min)"
    )
    console.print(
        f"versions: Python {info['python']}, numpy {info['numpy']}, OpenCV {info['opencv']} "
        f"({info['opencv_threads']} threads), {info['platform']}"
    )


def add_common_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="a run of seconds (keeps the script working)")
    parser.add_argument("--json", type=Path, default=None, metavar="FILE", help="also write results here")
    parser.add_argument("--repeat", type=int, default=None, help="runs per figure (the median is reported)")


def add_stereo_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--stereo",
        default=None,
        metavar="KEY=VALUE,...",
        help="stereo parameters over the defaults (YAML values), e.g. coarse_to_fine=false (the exact "
        "search) or lr_check=false",
    )


def stereo_overrides(text: str | None) -> dict[str, Any]:
    """``KEY=VALUE,...`` (``--stereo``) → a mapping (values read as YAML scalars: false, 20, 0.5)."""
    out: dict[str, Any] = {}
    for item in (text or "").split(","):
        if item.strip():
            key, _, value = item.partition("=")
            out[key.strip()] = yaml.safe_load(value)
    return out


def percentile(values: Sequence[float], q: float) -> float:
    """The q-th percentile (0..100, linear interpolation); NaN for no values."""
    if not values:
        return math.nan
    return float(np.percentile(np.asarray(values, dtype=np.float64), q))


def summary(values: Sequence[float]) -> dict[str, float]:
    """n, mean, p50, p95, p99, max of ``values`` (ms, s, ...)."""
    if not values:
        return {"n": 0, "mean": math.nan, "p50": math.nan, "p95": math.nan, "p99": math.nan, "max": math.nan}
    return {
        "n": len(values),
        "mean": float(statistics.fmean(values)),
        "p50": percentile(values, 50),
        "p95": percentile(values, 95),
        "p99": percentile(values, 99),
        "max": float(max(values)),
    }


def time_calls(fn: Callable[[], object], repeat: int, warmup: int = 1) -> list[float]:
    """Wall time (ms) of ``repeat`` calls of ``fn`` after ``warmup`` untimed ones."""
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t0) * 1e3)
    return out


def median(values: Iterable[float]) -> float:
    vals = [v for v in values if not math.isnan(v)]
    return float(statistics.median(vals)) if vals else math.nan


def finish(
    name: str,
    info_start: dict[str, Any],
    results: dict[str, Any],
    json_path: Path | None,
    table: Table | None,
) -> dict[str, Any]:
    """Print the table and the load at the end, write the JSON document; returns it."""
    if table is not None:
        console.print(table)
    end = os.getloadavg()
    console.print(
        f"load average at the end: {' / '.join(f'{x:.2f}' for x in end)} "
        "(figures taken under load are pessimistic; ratios share the load)"
    )
    doc = {
        "benchmark": name,
        "machine": info_start,
        "load_avg_end": [round(x, 2) for x in end],
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        **results,
    }
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps(doc, indent=2, default=_jsonable) + "\n")
        console.print(f"results written to {json_path}")
    return doc


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
