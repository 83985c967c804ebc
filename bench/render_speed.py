"""The renderer's speed: ``rig sim --preset prototype --scene room`` (the README's walkthrough)
with today's code against the renderer of an earlier commit, in the same run.

The earlier commit's ``rig`` and ``calibration`` packages are exported with ``git archive`` into a
temporary directory and imported from there in a child process; today's run in another child
process; the cases alternate for ``--repeat`` rounds and each figure is the median. Cases:

* **before**: the earlier commit's ``simulate_recording`` with its defaults (the preset's noise and
  vignetting, the Reference images): what ``rig sim`` did;
* **same output**: today's renderer asked for exactly that (``lens="ideal"``, the preset's
  noise and vignetting, ``reference=True``); its images and ground truth are compared with the
  earlier commit's (largest grey-level difference, largest relative range difference);
* **today's default**: the honest lens, no Reference images (what ``rig sim`` does now).

Figures: wall seconds per pair and CPU seconds per pair (the child's user + system time, every
thread), and each case's speed-up over **before** (wall and CPU). Then, with today's code, the CPU
seconds of ``rig serve --demo``'s one render of its room (``service.demo.render_demo``, the
default lat-lon pair; not with ``--quick``). A render has no OpenCV floor to
compare with; the ratio against the old implementation is the figure.

Run: ``.venv/bin/python -m bench.render_speed`` (``--quick``: quarter-size cameras, 1 frame, a
1.5 px/deg lat-lon pair).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from rich.table import Table

from bench.common import add_common_arguments, console, finish, machine_info, median, print_machine

__all__ = ["BEFORE_COMMIT", "main"]

REPO = Path(__file__).resolve().parent.parent
#: The last commit before the tiled, culled renderer.
BEFORE_COMMIT = "4c71b76"

_CHILD = """
import json, sys, time
from rig.sim import get_preset, simulate_recording
from rig.rectified import RectifiedPairConfig
args = json.loads(sys.argv[1])
preset = get_preset("prototype")
if args["scale"] != 1.0:
    preset = preset.scaled(args["scale"])
vpc = RectifiedPairConfig(**args["vpc"]) if args["vpc"] else None
t0 = time.perf_counter()
simulate_recording(preset, "room", args["out"], frames=args["frames"], vpc=vpc, **args["kwargs"])
print(json.dumps({"wall_s": time.perf_counter() - t0}))
"""
# --quick: a coarse lat-lon pair (the Reference images are most of the earlier renderer's work).
_QUICK_VPC = {"projection": "latlon", "px_per_deg": 1.5}

CASES: dict[str, dict[str, Any]] = {
    "before": {},
    "same output": {"lens": "ideal", "noise_std": 1.5, "vignetting": 0.35, "reference": True},
    "today's default": {},
}


def _export(commit: str, into: Path) -> Path:
    """``rig`` and ``calibration`` of ``commit`` under ``into``."""
    archive = into / "src.tar"
    with open(archive, "wb") as f:
        subprocess.run(["git", "archive", commit, "rig", "calibration"], cwd=REPO, stdout=f, check=True)
    src = into / "src"
    with tarfile.open(archive) as tar:
        tar.extractall(src, filter="data")
    return src


def _run(
    src: Path, out: Path, frames: int, scale: float, vpc: dict[str, Any] | None, kwargs: dict[str, Any]
) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": str(src)}
    doc = json.dumps({"out": str(out), "frames": frames, "scale": scale, "vpc": vpc, "kwargs": kwargs})
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    res = subprocess.run(
        [sys.executable, "-c", _CHILD, doc], cwd=src, env=env, check=True, capture_output=True, text=True
    )
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": float(json.loads(res.stdout.strip().splitlines()[-1])["wall_s"]), "cpu_s": cpu}


def _compare(a: Path, b: Path) -> dict[str, float]:
    """Largest grey-level difference of the fisheye and Reference images, and the largest
    relative difference of the ground-truth range (NaN where both are NaN)."""
    grey, rel = 0, 0.0
    subs = ("left", "right", "ground_truth/reference/left", "ground_truth/reference/right")
    for sub in subs:
        for f in sorted((a / sub).glob("*.png")):
            x, y = (
                np.asarray(cv2.imread(str(p), cv2.IMREAD_UNCHANGED), np.int32) for p in (f, b / sub / f.name)
            )
            grey = max(grey, int(np.abs(x - y).max()))
    for f in sorted((a / "ground_truth" / "range").glob("*.npy")):
        x, y = np.load(f).astype(np.float64), np.load(b / "ground_truth" / "range" / f.name)
        if not np.array_equal(np.isnan(x), np.isnan(y)):
            return {"max_grey_diff": float(grey), "max_range_rel_diff": float("inf")}
        both = np.isfinite(x)
        rel = max(rel, float(np.max(np.abs(x[both] - y[both]) / x[both], initial=0.0)))
    return {"max_grey_diff": float(grey), "max_range_rel_diff": rel}


def _demo_cpu_s() -> float:
    """CPU seconds (every thread) of the demo's render with today's code, in this process."""
    from service.demo import DemoSpec, render_demo  # only this figure needs the service

    with tempfile.TemporaryDirectory(prefix="render-speed-demo-") as tmp:
        c0 = time.process_time()
        render_demo(DemoSpec(), Path(tmp) / "demo")
        return time.process_time() - c0


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(
        prog="python -m bench.render_speed", description=__doc__.split("\n\n")[0]
    )
    add_common_arguments(parser)
    parser.add_argument(
        "--before", default=BEFORE_COMMIT, metavar="COMMIT", help="the earlier renderer's commit"
    )
    parser.add_argument("--frames", type=int, default=None, help="pairs per recording (default 3)")
    args = parser.parse_args(argv)
    frames = args.frames or (1 if args.quick else 3)
    scale = 0.25 if args.quick else 1.0
    repeat = args.repeat or (1 if args.quick else 2)
    info = machine_info()
    print_machine(info, f"rig sim --preset prototype --scene room --frames {frames}: today vs {args.before}")
    times: dict[str, list[dict[str, float]]] = {name: [] for name in CASES}
    with tempfile.TemporaryDirectory(prefix="render-speed-") as tmp:
        root = Path(tmp)
        sources = {"before": _export(args.before, root), "today": REPO}
        for k in range(repeat):
            for name, kwargs in CASES.items():
                src = sources["before" if name == "before" else "today"]
                out = root / f"{name.replace(' ', '_').replace(chr(39), '')}-{k}"
                times[name].append(_run(src, out, frames, scale, _QUICK_VPC if args.quick else None, kwargs))
                console.print(f"round {k + 1}/{repeat} {name}: {times[name][-1]['wall_s']:.1f} s wall")
        same = _compare(root / "before-0", root / "same_output-0")
    per_pair = {
        name: {key: median(t[key] for t in runs) / frames for key in ("wall_s", "cpu_s")}
        for name, runs in times.items()
    }
    table = Table(
        title=f"seconds per pair, median of {repeat} (prototype 1280x960 × {scale:g}, supersample 3)"
    )
    for col in ("case", "wall s/pair", "CPU s/pair", "pairs/s", "speed-up wall", "speed-up CPU"):
        table.add_column(col, justify="left" if col == "case" else "right")
    base = per_pair["before"]
    for name, fig in per_pair.items():
        table.add_row(
            name, f"{fig['wall_s']:.2f}", f"{fig['cpu_s']:.2f}", f"{1.0 / fig['wall_s']:.3f}",
            f"{base['wall_s'] / fig['wall_s']:.2f}×", f"{base['cpu_s'] / fig['cpu_s']:.2f}×",
        )  # fmt: skip
    console.print(
        f"same output vs before: largest grey-level difference {same['max_grey_diff']:g}, "
        f"largest relative range difference {same['max_range_rel_diff']:.2g}"
    )
    demo_cpu = None if args.quick else _demo_cpu_s()
    if demo_cpu is not None:
        console.print(
            f"rig serve --demo, its one render (render_demo, default lat-lon pair): {demo_cpu:.1f} s CPU"
        )
    results = {
        "frames": frames,
        "scale": scale,
        "repeat": repeat,
        "before": args.before,
        "per_pair": per_pair,
        "demo_render_cpu_s": demo_cpu,
    }
    return finish("render_speed", info, {**results, "same_output": same, "runs": times}, args.json, table)


if __name__ == "__main__":
    t0 = time.monotonic()
    main()
    console.print(f"took {time.monotonic() - t0:.0f} s")
