"""Image bombs through the real commands: a recording whose frame files include JPEGs (or PNGs)
of the right length whose header declares ``--size`` (30000×30000 by default).

Copies the benchmark's 1280×960 MJPEG recording (:mod:`bench.recordings`) to a scratch
directory, replaces the right frame of every ``--every``-th pair with a bomb made from that very
frame (its SOF0 marker, or a PNG's IHDR, rewritten: the same few tens of kilobytes), then runs

- ``rig process`` over it: exit status, peak RSS (the child's ``ru_maxrss`` from ``wait4``),
  wall time, how many pairs were written and which failures it reported;
- ``rig serve --recording`` on it for ``--seconds``: peak RSS against the memory budget it
  exports, depth frames made, frames counted corrupt or undecodable.

Run: ``.venv/bin/python -m bench.image_bombs`` (``--format png`` for PNG bombs).
"""

from __future__ import annotations

import argparse
import shutil
import struct
import tempfile
import time
import zlib
from pathlib import Path
from typing import Any

import cv2
import httpx
import numpy as np
from rich.table import Table

from bench.common import add_common_arguments, bench_cache_dir, console, finish, machine_info, print_machine
from bench.recordings import MjpegSpec, ensure_mjpeg_recording
from bench.service_proc import ServiceProcess, run_rig

__all__ = ["bomb", "bomb_recording", "main"]


def bomb(data: bytes, fmt: str, size: tuple[int, int] = (30000, 30000)) -> bytes:
    """``data`` with its header declaring ``size`` (JPEG: the SOF0 marker; PNG: IHDR and its CRC)."""
    out = bytearray(data)
    w, h = size
    if fmt == "jpeg":
        sof = out.find(b"\xff\xc0")
        out[sof + 5 : sof + 9] = struct.pack(">HH", h, w)
    else:
        out[16:24] = struct.pack(">II", w, h)
        out[29:33] = struct.pack(">I", zlib.crc32(bytes(out[12:29])) & 0xFFFFFFFF)
    return bytes(out)


def bomb_recording(source: Path, root: Path, fmt: str, every: int, size: tuple[int, int]) -> tuple[Path, int]:
    """A copy of ``source`` under ``root`` with every ``every``-th pair's right frame a bomb (PNG
    frames re-encoded for ``fmt`` png): the copy and how many bombs it holds."""
    rec = root / "bombs"
    shutil.copytree(source, rec)
    rows = (rec / "frames.csv").read_text().splitlines()
    out, bombs = [rows[0]], 0
    for k, row in enumerate(rows[1:]):
        seq, lts, rts, lfile, rfile = row.split(",")
        if fmt == "png":
            for name in (lfile, rfile):
                img = np.asarray(cv2.imread(str(rec / name), cv2.IMREAD_UNCHANGED))
                (rec / name).unlink()
                cv2.imwrite(str(rec / name.replace(".jpg", ".png")), img)
            lfile, rfile = lfile.replace(".jpg", ".png"), rfile.replace(".jpg", ".png")
        if k % every == every - 1:
            path = rec / rfile
            path.write_bytes(bomb(path.read_bytes(), fmt, size))
            bombs += 1
        out.append(",".join((seq, lts, rts, lfile, rfile)))
    (rec / "frames.csv").write_text("\n".join(out) + "\n")
    return rec, bombs


def _process(rec: Path, out: Path, env: dict[str, str]) -> dict[str, Any]:
    run = run_rig(["process", str(rec), "--out", str(out)], env)
    return {
        "exit_status": run.exit_status,
        "peak_rss_mb": run.peak_rss_mb,
        "seconds": run.seconds,
        "output": [ln[:160] for ln in run.lines[-4:]],
    }


def _serve(rec: Path, seconds: float, env: dict[str, str]) -> dict[str, Any]:
    with ServiceProcess(["--recording", str(rec), "--log-level", "warning"], env) as svc:
        svc.wait_ready(600.0)
        peak, until = svc.rss_mb(), time.monotonic() + seconds
        with httpx.Client(timeout=30.0) as c:
            first = c.get(svc.url + "/health").json()
            while time.monotonic() < until:
                time.sleep(0.25)
                peak = max(peak, svc.rss_mb())
            last = c.get(svc.url + "/health").json()
            metrics = c.get(svc.url + "/metrics").text
    budgets = [
        float(x.split()[1]) / 2**20 for x in metrics.splitlines() if x.startswith("rig_memory_budget_bytes ")
    ]

    def counted(doc: dict[str, Any], name: str) -> int:
        return sum(int(cam.get(name) or 0) for cam in doc["cameras"].values())

    return {
        "peak_rss_mb": peak,
        "budget_mb": budgets[0] if budgets else None,
        "depth_frames": last["worker"]["frames_processed"] - first["worker"]["frames_processed"],
        "corrupt_or_undecodable": sum(
            counted(last, n) - counted(first, n) for n in ("frames_corrupt", "frames_undecodable")
        ),
        "status": last["status"],
        "reasons": [r[:160] for r in last["reasons"][:2]],
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m bench.image_bombs", description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    parser.add_argument("--format", choices=("jpeg", "png"), default="jpeg")
    parser.add_argument("--every", type=int, default=4, help="a bomb every this many pairs")
    parser.add_argument("--size", type=int, nargs=2, default=(30000, 30000), metavar=("W", "H"))
    parser.add_argument("--seconds", type=float, default=20.0, help="rig serve's run")
    args = parser.parse_args(argv)
    info = machine_info()
    print_machine(info, "Image bombs through rig process and rig serve")
    source = ensure_mjpeg_recording(MjpegSpec())
    env = {"RIG_CACHE_DIR": str(bench_cache_dir() / "lut")}
    with tempfile.TemporaryDirectory(prefix="rig-bombs-") as tmp:
        rec, bombs = bomb_recording(source, Path(tmp), args.format, args.every, tuple(args.size))
        sizes = sorted({p.stat().st_size for p in (rec / "right").iterdir()})
        console.print(f"{bombs} bombs in {len(sizes)} right frames of {sizes[0]}-{sizes[-1]} bytes")
        results: dict[str, Any] = {"format": args.format, "bombs": bombs, "size": list(args.size)}
        results["process"] = _process(rec, Path(tmp) / "out", env)
        console.print("rig process done")
        results["serve"] = _serve(rec, args.seconds, env)
    table = Table(title=f"{args.format} bombs declaring {args.size[0]}x{args.size[1]}")
    table.add_column("command")
    table.add_column("figures")
    for name in ("process", "serve"):
        table.add_row(name, "\n".join(f"{k}: {v}" for k, v in results[name].items()))
    return finish("image_bombs", info, results, args.json, table)


if __name__ == "__main__":
    main()
