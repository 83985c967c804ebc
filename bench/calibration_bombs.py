"""Calibration files that cost too much, through the real command: each given to
``rig lut build --calibration FILE``, which reads it as a rig.

- ``pol2000``: an OCamCalib file (the shared data's vivekmudgal one) whose ``pol`` line declares
  2000 coefficients (``--huge`` adds one of 50 000: before the bound, it ran out of 21 GB);
- ``deep-xml``: OpenCV FileStorage XML nested 100 000 elements deep;
- ``row-yaml``: a YAML ``K`` row of a million numbers (5 MB); ``row100k-yaml``: of 100 000 (500 kB);
- ``deep-yaml``: a YAML flow sequence nested 5000 deep.

Per file: exit status (negative: the signal that ended it), seconds, the child's peak RSS and the
first line it printed. A run is killed after ``--timeout`` seconds.

Run: ``.venv/bin/python -m bench.calibration_bombs`` (needs ``RIG_SHARED_DATA`` or
../shared/data for the OCamCalib file).
"""

from __future__ import annotations

import argparse
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rich.table import Table

from bench.common import add_common_arguments, finish, machine_info, print_machine
from bench.service_proc import REPO, run_rig

__all__ = ["BOMBS", "main"]


def _ocamcalib_with_pol(n: int) -> str:
    data = Path(os.environ.get("RIG_SHARED_DATA", REPO.parent / "shared" / "data"))
    lines = (data / "ocamcalib_vivekmudgal" / "calib_results.txt").read_text().splitlines()
    first = next(i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#"))
    coefficients = lines[first].split()[1:]
    lines[first] = f"{n} " + " ".join(coefficients + ["1e-30"] * (n - len(coefficients)))
    return "\n".join(lines) + "\n"


def _xml_nested(depth: int) -> str:
    nested = "<a>" * depth + "1" + "</a>" * depth
    return f'<?xml version="1.0"?>\n<opencv_storage>\n{nested}\n</opencv_storage>\n'


def _numbers_row(n: int) -> str:
    return "K: [" + ", ".join("1.5" for _ in range(n)) + "]\nD: [0, 0, 0, 0]\n"


BOMBS: dict[str, tuple[str, Callable[[], str]]] = {
    "pol2000": ("calib_results.txt", lambda: _ocamcalib_with_pol(2000)),
    "deep-xml": ("deep.xml", lambda: _xml_nested(100_000)),
    "row-yaml": ("row.yaml", lambda: _numbers_row(1_000_000)),
    "row100k-yaml": ("row100k.yaml", lambda: _numbers_row(100_000)),
    "deep-yaml": ("deep.yaml", lambda: "K: " + "[" * 5000 + "1" + "]" * 5000 + "\n"),
}
HUGE = {"pol50000": ("calib_results.txt", lambda: _ocamcalib_with_pol(50_000))}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    description = __doc__.split("\n\n")[0]
    parser = argparse.ArgumentParser(prog="python -m bench.calibration_bombs", description=description)
    add_common_arguments(parser)
    parser.add_argument("--huge", action="store_true", help="also the 50 000-coefficient polynomial")
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds before a run is killed")
    args = parser.parse_args(argv)
    info = machine_info()
    print_machine(info, "Calibration files that cost too much: rig lut build --calibration FILE")
    results: dict[str, Any] = {}
    table = Table(title="rig lut build --calibration FILE")
    for column in ("file", "exit", "seconds", "peak RSS MB", "first line"):
        table.add_column(column)
    with tempfile.TemporaryDirectory(prefix="rig-calibration-bombs-") as tmp:
        for name, (file_name, text) in {**BOMBS, **(HUGE if args.huge else {})}.items():
            path = Path(tmp) / name / file_name
            path.parent.mkdir()
            path.write_text(text())
            command = ["lut", "build", "--calibration", str(path), "--cache-dir", str(Path(tmp) / "cache")]
            run = run_rig(command, timeout_s=args.timeout)
            first = run.lines[0][:150] if run.lines else ""
            results[name] = {
                "bytes": path.stat().st_size,
                "exit_status": run.exit_status,
                "seconds": run.seconds,
                "peak_rss_mb": run.peak_rss_mb,
                "first_line": first,
            }
            table.add_row(name, str(run.exit_status), f"{run.seconds:.1f}", f"{run.peak_rss_mb:.0f}", first)
    return finish("calibration_bombs", info, results, args.json, table)


if __name__ == "__main__":
    main()
