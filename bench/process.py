"""``rig process`` against the bare OpenCV floor, per pair and at start-up.

Input: the MJPEG recording of :mod:`bench.recordings` (``--pairs`` pairs of 1280×960 colour 4:2:2
JPEG frames of the prototype rig in the demo room, each with fresh sensor noise), read from disk.

**Floor** — a loop over the recording doing only the bare calls of the same work, per pair: read
both files, ``cv2.imdecode`` ×2 (``IMREAD_UNCHANGED``: colour, as ``rig process`` reads frames to
write colour VPC images), ``cv2.remap`` ×2 with the pipeline's fixed-point maps, ``cv2.cvtColor``
to gray ×2, ``compute`` of a ``cv2.StereoSGBM`` with the same parameters (twice with ``lr_check``,
the default: the second run on the mirrored pair, as the left-right check does), ``cv2.divide`` of the
fixed-point disparity into uint16 millimetres of depth, and ``cv2.imwrite`` of the depth and both
VPC images as PNG (OpenCV's default PNG settings, the encoder ``rig process`` uses too). With
``--projection latlon`` (the product's default pair, its default 96 disparities) the floor writes
the range instead of the depth, as ``rig process`` does for that pair: ``B·(cos α·cot δ + sin α)``
in uint16 millimetres from the disparity δ and the column's azimuth α, in numpy (there is no
OpenCV call for it).

**Ours** — :func:`rig.process.process_recordings` in this process (what ``rig process REC --out
DIR`` runs): the staged pipeline with the default stages (subpixel refinement, confidence, 5×5
median; the floor has none of them), reading ahead, atomic and fsynced writes, ``vpc.json`` and
``run.json``. Its per-pair throughput is timed between its first and its last pair (the
progress callback); the rest of a run (the stages filling and draining, planning the output
directory) is its fixed cost, reported apart.

Throughput is timed in alternating windows (ours, floor / floor, ours: a steady drift of the
machine's speed cancels), a ratio per window pair; medians and interquartile ranges over
``--windows`` pairs. Each window is one whole run over the recording into a fresh directory on
the same file system.

**Start-up**: the wall time of ``python -c pass`` (Python's own), of ``rig process --help``, the
import time ``python -X importtime -m cli process --help`` reports, and the wall time of ``rig
process`` on a one-pair copy of the recording (warm LUT cache): less Python's own start and the
floor's time for that pair, it is the fixed cost of a run beyond Python's (target under 1 s).

Run: ``flock /tmp/rig-bench.lock .venv/bin/python -m bench.process`` (``--quick``: seconds).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml
from rich.table import Table

from bench.common import (
    add_common_arguments,
    add_stereo_argument,
    console,
    finish,
    machine_info,
    median,
    percentile,
    print_machine,
    stereo_overrides,
)
from bench.recordings import MjpegSpec, ensure_mjpeg_recording
from bench.worker import floor_match, floor_matcher
from calibration import load_rig
from calibration.models import LatLonModel
from rig.pipeline import DepthPipeline
from rig.process import process_recordings
from rig.recording import Recording, RecordingWriter
from rig.recording_jobs import ProcessOptions, RecordingJob, RecordingSource
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams

__all__ = ["BenchInput", "OursRun", "bench_input", "main", "run_floor", "run_ours", "startup_figures"]

REPO = Path(__file__).resolve().parents[1]
RIG = str(Path(sys.executable).with_name("rig"))


@dataclass(frozen=True)
class BenchInput:
    """The recording, its calibration, the pipeline of the measured configuration and a
    scratch directory on the file system the outputs go to."""

    recording: Path
    pipeline: DepthPipeline
    scratch: Path

    @property
    def pairs(self) -> int:
        return len(Recording(self.recording).pairs)


def bench_input(spec: MjpegSpec, vpc: RectifiedPairConfig, stereo: StereoParams, scratch: Path) -> BenchInput:
    recording = ensure_mjpeg_recording(spec)
    pipeline = DepthPipeline(load_rig(recording / "calibration.yaml"), vpc, stereo, cache_dir=scratch / "lut")
    return BenchInput(recording, pipeline, scratch)


@dataclass(frozen=True)
class FloorRun:
    pair_ms: list[float]
    pairs_per_s: float


@dataclass(frozen=True)
class OursRun:
    """A run over the recording: pairs per second between its first and last pair, the
    run's wall time, and its fixed cost (wall time less the pairs at that rate)."""

    pairs_per_s: float
    wall_s: float
    fixed_s: float
    failures: int
    written: int


def run_floor(data: BenchInput, out: Path) -> FloorRun:
    """The bare calls (see the module doc) over every pair, writing into ``out``."""
    rec, pipe = Recording(data.recording), data.pipeline
    left_lut, right_lut = (pipe.luts[n] for n in pipe.names)
    sgbm = floor_matcher(pipe.stereo)
    mirrored = pipe.stereo.lr_check
    to_mm = _floor_millimetres(pipe)
    product = "range" if pipe.pair.projection == "latlon" else "depth"
    for sub in (product, "left", "right"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    decode: Any = cv2.imdecode  # typed loosely: the floor is the bare calls, no checks
    times = []
    t_start = time.perf_counter()
    for pair in rec.pairs:
        t0 = time.perf_counter()
        views = []
        for cam, lut in (("left", left_lut), ("right", right_lut)):
            data_bytes = rec.path(pair.file(cam)).read_bytes()
            img = decode(np.frombuffer(data_bytes, np.uint8), cv2.IMREAD_UNCHANGED)
            views.append(cv2.remap(img, lut.map1, lut.map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT))
        grays = [cv2.cvtColor(v, cv2.COLOR_BGR2GRAY) if v.ndim == 3 else v for v in views]
        millimetres = to_mm(floor_match(sgbm, grays[0], grays[1], mirrored))
        name = f"{pair.seq:06d}.png"
        cv2.imwrite(str(out / product / name), millimetres)
        cv2.imwrite(str(out / "left" / name), views[0])
        cv2.imwrite(str(out / "right" / name), views[1])
        times.append((time.perf_counter() - t0) * 1e3)
    return FloorRun(times, len(times) / (time.perf_counter() - t_start))


def _floor_millimetres(pipe: DepthPipeline) -> Any:
    """The floor's fixed-point disparity → uint16 mm: the pinhole's depth (one ``cv2.divide``) or
    the lat-lon pair's range along the ray (per-column azimuths, in numpy); 0 = invalid."""
    fx, baseline, camera = pipe.pair.fx, pipe.baseline_m, pipe.pair.camera
    if not isinstance(camera, LatLonModel):
        mm16 = 1000.0 * 16.0 * fx * baseline  # depth in mm = this / fixed-point disparity
        return lambda fixed: cv2.divide(mm16, fixed, dtype=cv2.CV_16U)
    azimuths = camera.azimuths()
    cos_a = (1000.0 * baseline * np.cos(azimuths)).astype(np.float32)
    sin_a = (1000.0 * baseline * np.sin(azimuths)).astype(np.float32)

    def latlon_mm(fixed: Any) -> Any:
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            r = cos_a / np.tan(fixed * np.float32(1.0 / (16.0 * fx))) + sin_a
        r[fixed <= 0] = 0
        return np.clip(np.nan_to_num(r, nan=0.0, posinf=0.0), 0, 65535).astype(np.uint16)

    return latlon_mm


def run_ours(
    data: BenchInput, recordings: list[Path], out: Path, scheduler: str | None = None, chunk_pairs: int = 32
) -> OursRun:
    """:func:`process_recordings` over ``recordings`` into ``out/NAME`` (see the module doc)."""
    jobs = [RecordingJob(RecordingSource(r), Recording(r), data.pipeline, out / r.name) for r in recordings]
    stamps: list[float] = []
    t0 = time.perf_counter()
    summaries = process_recordings(
        jobs,
        ProcessOptions(chunk_pairs=chunk_pairs),
        scheduler=scheduler,
        on_progress=lambda *_: stamps.append(time.perf_counter()),
    )
    wall = time.perf_counter() - t0
    pairs = sum(s.written for s in summaries)
    rate = (len(stamps) - 1) / (stamps[-1] - stamps[0]) if len(stamps) > 1 else float("nan")
    return OursRun(rate, wall, wall - pairs / rate, sum(len(s.failures) for s in summaries), pairs)


def _wall(args: list[str], env: dict[str, str] | None = None) -> float:
    t0 = time.perf_counter()
    subprocess.run(args, check=True, capture_output=True, env=env, cwd=REPO)
    return time.perf_counter() - t0


def _import_s() -> float:
    """Total import time ``python -X importtime -m cli process --help`` reports."""
    res = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "cli", "process", "--help"],
        capture_output=True,
        text=True,
        check=True,
        cwd=REPO,
    )
    total = 0
    for line in res.stderr.splitlines():
        parts = line.split("|")
        if line.startswith("import time:") and len(parts) == 3 and parts[0].split(":")[1].strip().isdigit():
            total += int(parts[0].split(":")[1])
    return total / 1e6


def one_pair_copy(recording: Path, out: Path) -> Path:
    """The recording's first pair alone, with its calibration."""
    src = Recording(recording)
    pair = src.pairs[0]
    with RecordingWriter(out, meta={"generator": "bench.process"}) as writer:
        writer.write_pair(
            pair.seq,
            pair.left_ts_ns,
            pair.right_ts_ns,
            src.read_bytes(pair, "left"),
            src.read_bytes(pair, "right"),
        )
    shutil.copyfile(recording / "calibration.yaml", out / "calibration.yaml")
    return out


def startup_figures(data: BenchInput, vpc_args: list[str], stereo_file: Path, repeat: int) -> dict[str, Any]:
    """Python's own start, ``rig process --help`` and a one-pair run, medians of ``repeat``."""
    env = {**os.environ, "RIG_CACHE_DIR": str(data.scratch / "lut")}
    one = one_pair_copy(data.recording, data.scratch / "one")
    runs: dict[str, list[float]] = {"python": [], "help": [], "imports": [], "one_pair": []}
    for k in range(repeat):
        runs["python"].append(_wall([sys.executable, "-c", "pass"]))
        runs["help"].append(_wall([RIG, "process", "--help"]))
        runs["imports"].append(_import_s())
        out = data.scratch / f"one-out-{k}"
        runs["one_pair"].append(
            _wall([RIG, "process", str(one), "--out", str(out), *vpc_args, "--stereo", str(stereo_file)], env)
        )
        shutil.rmtree(out, ignore_errors=True)
    return {k: median(v) for k, v in runs.items()} | {"runs": runs}


def _windows(data: BenchInput, windows: int) -> list[tuple[FloorRun, OursRun]]:
    out = []
    for i in range(windows):
        floor_dir, ours_dir = data.scratch / f"floor-{i}", data.scratch / f"ours-{i}"
        if i % 2 == 0:
            ours = run_ours(data, [data.recording], ours_dir)
            floor = run_floor(data, floor_dir)
        else:
            floor = run_floor(data, floor_dir)
            ours = run_ours(data, [data.recording], ours_dir)
        shutil.rmtree(floor_dir)
        shutil.rmtree(ours_dir)
        out.append((floor, ours))
    return out


def _configuration(
    projection: str, quick: bool, disparities: int | None = None, overrides: dict[str, Any] | None = None
) -> tuple[RectifiedPairConfig, StereoParams, list[str]]:
    """The measured pair, its stereo parameters (``disparities``, else the pair's own default:
    96 for the lat-lon pair, 128 for the pinhole pair as measured first; ``overrides`` over
    them) and the ``rig process`` options that choose the pair."""
    if projection == "latlon":
        stereo = StereoParams(disparity_range=32 if quick else disparities or 96, **(overrides or {}))
        return (
            RectifiedPairConfig(px_per_deg=1.5) if quick else RectifiedPairConfig(),
            stereo,
            ["--projection", "latlon"] + (["--px-per-deg", "1.5"] if quick else []),
        )
    w, h, disp = (160, 120, 32) if quick else (640, 480, disparities or 128)
    return (
        RectifiedPairConfig(width=w, height=h),
        StereoParams(disparity_range=disp, **(overrides or {})),
        ["--vpc-size", f"{w}x{h}"],
    )


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m bench.process", description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    parser.add_argument("--pairs", type=int, default=None, help="pairs in the recording")
    parser.add_argument("--windows", type=int, default=None, help="floor / ours window pairs")
    parser.add_argument(
        "--projection",
        choices=("pinhole", "latlon"),
        default="pinhole",
        help="the rectified pair: the pinhole pair (640×480, 128 disparities) or the default lat-lon pair",
    )
    parser.add_argument("--disparities", type=int, default=None, help="disparity_range (default: the pair's)")
    add_stereo_argument(parser)
    args = parser.parse_args(argv)
    quick = args.quick
    spec = MjpegSpec(frames=4, views=1, scale=0.25) if quick else MjpegSpec(frames=args.pairs or 24)
    overrides = stereo_overrides(args.stereo)
    vpc, stereo, vpc_args = _configuration(args.projection, quick, args.disparities, overrides)
    windows = args.windows or (2 if quick else 8)
    repeat = args.repeat or (1 if quick else 5)
    info = machine_info()
    print_machine(info, "rig process vs the bare OpenCV floor")
    with tempfile.TemporaryDirectory(
        prefix="rig-bench-process-", dir=os.environ.get("RIG_BENCH_SCRATCH")
    ) as tmp:
        data = bench_input(spec, vpc, stereo, Path(tmp))
        cam = data.pipeline.pair.camera
        w, h, disp = cam.width, cam.height, stereo.disparity_range
        label = f"{'lat-lon ' if data.pipeline.pair.projection == 'latlon' else ''}{w}×{h}"
        console.print(
            f"input: {data.recording} ({data.pairs} pairs, colour JPEG q{spec.quality}); VPC {label}, "
            f"{disp} disparities{', ' + args.stereo if args.stereo else ''}; {windows} alternating window "
            "pairs, one run over the recording each"
        )
        run_floor(data, data.scratch / "warm")  # page cache, encoder and matcher warm for both
        pairs = _windows(data, windows)
        stereo_file = data.scratch / "stereo.yaml"
        stereo_file.write_text(yaml.safe_dump({"disparity_range": disp, **overrides}))
        start = startup_figures(data, vpc_args, stereo_file, repeat)
    ratios = [o.pairs_per_s / f.pairs_per_s for f, o in pairs]
    floor_ms = median(median(f.pair_ms) for f, _ in pairs)
    row = {
        "vpc": [w, h],
        "projection": data.pipeline.pair.projection,
        "disparities": disp,
        "pairs": data.pairs,
        "floor_ms_per_pair": floor_ms,
        "floor_pairs_per_s": median(f.pairs_per_s for f, _ in pairs),
        "ours_pairs_per_s": median(o.pairs_per_s for _, o in pairs),
        "throughput_ratio": median(ratios),
        "throughput_ratio_iqr": [percentile(ratios, 25), percentile(ratios, 75)],
        "ours_fixed_s": median(o.fixed_s for _, o in pairs),
        "failures": sum(o.failures for _, o in pairs),
        "startup": start,
        "fixed_beyond_python_s": start["one_pair"] - start["python"] - floor_ms / 1e3,
        "runs": {
            "floor_pairs_per_s": [f.pairs_per_s for f, _ in pairs],
            "ours_pairs_per_s": [o.pairs_per_s for _, o in pairs],
            "throughput_ratio": ratios,
        },
    }
    table = Table(
        title="rig process per pair: floor (bare OpenCV) vs ours (the staged pipeline, default stages"
        f"{', ' + args.stereo if args.stereo else ''})"
    )
    for col in (
        "VPC",
        "disp",
        "floor ms/pair",
        "floor pairs/s",
        "ours pairs/s",
        "ours × floor (IQR)",
        "ours fixed s",
    ):
        table.add_column(col, justify="right")
    q1, q3 = row["throughput_ratio_iqr"]
    table.add_row(
        label,
        str(disp),
        f"{floor_ms:.1f}",
        f"{row['floor_pairs_per_s']:.2f}",
        f"{row['ours_pairs_per_s']:.2f}",
        f"{row['throughput_ratio']:.2f} ({q1:.2f}–{q3:.2f})",
        f"{row['ours_fixed_s']:.2f}",
    )
    console.print(table)
    start_table = Table(title=f"start-up, median of {repeat} (s)")
    for col in (
        "python -c pass",
        "rig process --help",
        "its imports",
        "rig process, 1 pair",
        "fixed cost beyond Python",
    ):
        start_table.add_column(col, justify="right")
    start_table.add_row(
        f"{start['python']:.2f}",
        f"{start['help']:.2f}",
        f"{start['imports']:.2f}",
        f"{start['one_pair']:.2f}",
        f"{row['fixed_beyond_python_s']:.2f}",
    )
    console.print(
        "ours × floor = ours pairs/s (first to last pair of a run) / the floor's pairs/s, per window pair "
        "(target ≥ 1.0); ours fixed s = a run's wall time less its pairs at its rate; fixed cost beyond "
        "Python = the one-pair run less python -c pass and the floor's time for one pair (target < 1 s)"
    )
    return finish(
        "process",
        info,
        {"spec": spec.__dict__, "windows": windows, "repeat": repeat, "rows": [row]},
        args.json,
        start_table,
    )


if __name__ == "__main__":
    main()
