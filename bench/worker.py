"""Worker path against the OpenCV floor (docs/performance.md).

Input: a recording of 1280×960 MJPEG fisheye frames (:mod:`bench.recordings`, built once).

**Floor** — a tight Python loop over the same JPEG bytes in memory doing only the bare OpenCV
calls the depth needs: ``cv2.imdecode`` ×2 to gray (what :attr:`rig.capture.frame.Frame.gray`,
the worker's decode, does: depth needs only luma), ``cv2.remap`` ×2 with the pipeline's own
fixed-point maps, and ``compute`` of a ``cv2.StereoSGBM`` built with the same parameters
(checked to give the identical disparity as the pipeline's matcher), run a second time on the
mirrored pair when the left-right check is on (``lr_check``, a default), both on the whole image
(ours' second run matches only the columns the right lens sees, :class:`rig.stereo.SeenColumns`).
Per-frame time = one iteration; throughput = frames / time.

**Ours** — the service itself minus HTTP: :meth:`service.runtime.Runtime.build` on settings whose
cameras are file cameras replaying the recording (``FileCamera`` → ``StereoCapture`` →
``DepthWorker`` → ``DepthPipeline`` with its default stages: subpixel refinement, confidence,
5×5 median). Throughput: unpaced replay (``pace: fast`` with back-pressure, one pair buffered),
pairs published per second. Latency: pair arrival (the later frame's host time,
before decoding) → depth published, per frame, with the cameras paced at 60 % of the measured
throughput so that no pair waits behind another (the latency of a frame, not of a queue).

**Same work** — the same frames through the library in a plain loop: ``cv2.imdecode`` ×2 to
gray, then :meth:`rig.pipeline.DepthPipeline.process` with ours' stages (the finish stage's row
bands on the pipeline's pool, as in ours). The floor is the issue's reference (decode, remap,
matcher); the same-work loop is the reference for the stages the floor leaves out, so that
``ours / same work`` is what the service's threads gain (or cost) on the work it really does.

``--stages floor`` runs ours with only the floor's work (plain SGBM: no refinement, confidence or
median), which isolates what the service's threads and glue cost or gain; the default stages add
the refinement that takes SGBM's ~0.2 px pixel-locking error to ~0.03 px.

Throughput and latency are each timed in alternating short windows of one run
(:mod:`bench.alternating`): ours' runtime stays up and is paused while the floor runs, and each
ratio compares a window of each, seconds apart (the VM's speed drifts between minutes). Their
medians and interquartile ranges over ``--windows`` pairs are reported, with the process CPU per
frame and the cores kept busy: the *CPU ceiling* is the rate ours' CPU per frame would allow with
every core busy, against the floor's rate (a throughput ratio above it is impossible on the
machine). The same-work loop runs ``--repeat`` times after them.
Run: ``.venv/bin/python -m bench.worker`` (``--quick`` for a run of seconds).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray
from rich.table import Table

from bench.alternating import Window, WorkerSession
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
    summary,
)
from bench.recordings import MjpegSpec, ensure_mjpeg_recording, load_jpeg_pairs
from calibration import load_rig
from rig.capture.config import CaptureConfig, FileCameraConfig, PairingConfig, SupervisorConfig
from rig.pipeline import DepthPipeline
from rig.rectification import RectificationConfig
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoMatcher, StereoParams, create_opencv_matcher
from service.settings import CalibrationSettings, ServerSettings, Settings

__all__ = ["FloorRun", "floor_matcher", "main", "measure_config", "run_floor", "run_same_work"]

FULL_SIZES = ((320, 240), (640, 480), (1280, 960))
FULL_DISPARITIES = (64, 128)
LATENCY_PACE_FRACTION = 0.6
# What rig.capture.frame.Frame.gray, the worker's decode, decodes JPEG with.
FLOOR_DECODE = cv2.IMREAD_GRAYSCALE
# ``--decode``: cameras.supervisor.decode of each choice.
DECODE_MODES: dict[str, bool | Literal["auto"]] = {"auto": "auto", "capture": True, "worker": False}
# Stereo parameters of ``--stages``: the service's defaults, or none of our stages after the matcher.
STAGES: dict[str, dict[str, Any]] = {
    "default": {},
    "floor": {"subpixel": False, "confidence": False, "median": 0},
}


@dataclass(frozen=True)
class FloorRun:
    frame_ms: list[float]
    fps: float
    cpu_ms: float  # process CPU time per frame (all threads)


def floor_matcher(params: StereoParams) -> Any:
    """A bare ``cv2.StereoSGBM`` with ``params`` (the same constructor :class:`StereoMatcher` uses)."""
    if params.stereo_algorithm != 1:
        raise SystemExit("the floor is written for SGBM (stereo_algorithm 1)")
    return create_opencv_matcher(params)


def floor_match(sgbm: Any, left: Any, right: Any, lr_check: bool) -> Any:
    """The bare matcher on a rectified gray pair, and with ``lr_check`` its second run on the
    mirrored pair (the work the left-right check adds, as :class:`rig.stereo.StereoMatcher` does
    it); the first run's fixed-point disparity."""
    disparity = sgbm.compute(left, right)
    if lr_check:
        sgbm.compute(np.ascontiguousarray(right[:, ::-1]), np.ascontiguousarray(left[:, ::-1]))
    return disparity


def _timed_loop(pairs: list[tuple[bytes, bytes]], frames: int, step: Any) -> FloorRun:
    """``step(left_bytes, right_bytes)`` (numpy views of the JPEGs) over ``frames`` pairs, cycling
    through ``pairs``: per-frame times, frames per second and process CPU per frame."""
    bufs = [(np.frombuffer(a, np.uint8), np.frombuffer(b, np.uint8)) for a, b in pairs]
    times: list[float] = []
    c_start, t_start = time.process_time(), time.perf_counter()
    for i in range(frames):
        bl, br = bufs[i % len(bufs)]
        t0 = time.perf_counter()
        step(bl, br)
        times.append((time.perf_counter() - t0) * 1e3)
    total = time.perf_counter() - t_start
    cpu = time.process_time() - c_start
    return FloorRun(times, frames / total, cpu * 1e3 / frames)


def run_floor(
    pairs: list[tuple[bytes, bytes]], pipeline: DepthPipeline, sgbm: Any, frames: int, flags: int
) -> FloorRun:
    """The bare OpenCV loop (see module doc) over ``frames`` pairs (cycling through ``pairs``)."""
    left_lut, right_lut = (pipeline.luts[n] for n in pipeline.names)
    lm1, lm2, rm1, rm2 = left_lut.map1, left_lut.map2, right_lut.map1, right_lut.map2
    decode: Any = cv2.imdecode  # typed loosely: the floor is the bare calls, no checks
    remap: Any = cv2.remap

    mirrored = pipeline.stereo.lr_check

    def step(bl: Any, br: Any) -> None:
        left = decode(bl, flags)
        right = decode(br, flags)
        lv = remap(left, lm1, lm2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        rv = remap(right, rm1, rm2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        floor_match(sgbm, lv, rv, mirrored)

    return _timed_loop(pairs, frames, step)


def run_same_work(
    pairs: list[tuple[bytes, bytes]], pipeline: DepthPipeline, frames: int, flags: int
) -> FloorRun:
    """The same work as ours in a plain loop: decode both frames, then
    :meth:`DepthPipeline.process` (remap, matcher and every configured stage, one call after the
    other; the finish stage's row bands on the pipeline's own pool) — the library as a script
    would call it, without the service's stage threads."""
    decode: Any = cv2.imdecode

    def step(bl: Any, br: Any) -> None:
        pipeline.process(decode(bl, flags), decode(br, flags))

    return _timed_loop(pairs, frames, step)


def check_floor_matcher(pairs: list[tuple[bytes, bytes]], pipeline: DepthPipeline, sgbm: Any) -> None:
    """The floor's matcher gives exactly the pipeline's raw disparity on the first pair."""
    left = _decode(pairs[0][0])
    right = _decode(pairs[0][1])
    lv, rv = pipeline.remap(left, right)
    ours = StereoMatcher(pipeline.stereo).raw(lv, rv)
    bare = sgbm.compute(lv, rv)
    if not np.array_equal(ours, bare):
        raise SystemExit("the floor's matcher differs from the pipeline's: not the same parameters")


def _decode(data: bytes) -> NDArray[np.uint8]:
    img = cv2.imdecode(np.frombuffer(data, np.uint8), FLOOR_DECODE)
    if img is None:
        raise SystemExit("a benchmark frame does not decode")
    return np.asarray(img, dtype=np.uint8)


def bench_settings(
    recording: Path,
    vpc: RectifiedPairConfig,
    stereo: StereoParams,
    lut_dir: Path,
    scratch: Path,
    *,
    pace: str | float,
    decode: bool | Literal["auto"],
) -> Settings:
    fast = pace == "fast"
    cams = {
        "kind": "file",
        "recording": recording,
        "pace": pace,
        "loop": True,
        "timestamps": "recorded" if fast else "live",
    }
    capture = CaptureConfig(
        left=FileCameraConfig.model_validate({**cams, "camera": "left"}),
        right=FileCameraConfig.model_validate({**cams, "camera": "right"}),
        # Unpaced: the cameras wait for the worker (nothing dropped, one pair ready in advance).
        pairing=PairingConfig(backpressure=True, pair_buffer=1) if fast else PairingConfig(),
        # A camera waiting under back-pressure delivers nothing: not a stall for the watchdog.
        supervisor=SupervisorConfig(decode=decode, watchdog_s=120.0, reconnect_after_s=240.0)
        if fast
        else SupervisorConfig(decode=decode),
    )
    return Settings(
        server=ServerSettings(recordings_dir=scratch / "recordings"),
        cameras=capture,
        calibration=CalibrationSettings(path=recording / "calibration.yaml"),
        vpc=vpc,
        stereo=stereo,
        cache_dir=lut_dir,
        # The rectification monitor's check (every 10 s, low priority) would also run while the
        # floor has the machine: both sides do the same work here; bench.rectification times it.
        rectification=RectificationConfig(enabled=False),
    )


def _configs(quick: bool) -> list[tuple[RectifiedPairConfig, int]]:
    if quick:
        return [(RectifiedPairConfig(width=160, height=120), 32)]
    return [(RectifiedPairConfig(width=w, height=h), d) for (w, h) in FULL_SIZES for d in FULL_DISPARITIES]


def parse_config(item: str) -> tuple[RectifiedPairConfig, int]:
    """``640x480/128`` (a pinhole pair), ``latlon/128`` (the lat-lon pair at its default
    resolution) or ``latlon@4.5/128`` (at 4.5 px/deg): the rectified pair and its disparities."""
    view, disp = item.split("/")
    view = view.strip().lower()
    if view.startswith("latlon"):
        ppd = float(view.split("@", 1)[1]) if "@" in view else None
        return RectifiedPairConfig(projection="latlon", px_per_deg=ppd), int(disp)
    w, h = (int(v) for v in view.split("x"))
    return RectifiedPairConfig(width=w, height=h), int(disp)


def _label(row: dict[str, Any]) -> str:
    w, h = row["vpc"]
    return f"{w}×{h}" + (f" lat-lon {row['px_per_deg']:.2f} px/deg" if row["projection"] == "latlon" else "")


def _quartiles(values: list[float]) -> tuple[float, float]:
    """The 25th and 75th percentiles of ``values`` (NaN for none)."""
    return percentile(values, 25), percentile(values, 75)


@dataclass(frozen=True)
class Measure:
    """How long and how often each figure is measured (see ``--help``)."""

    windows: int  # floor / ours window pairs per figure, for throughput and again for latency
    window_s: float
    repeat: int  # same-work runs per figure
    seconds: float  # length of each same-work run
    warmup_s: float  # ours' discarded first window


def alternate_windows(
    session: WorkerSession,
    pairs: list[tuple[bytes, bytes]],
    pipeline: DepthPipeline,
    sgbm: Any,
    n_floor: int,
    m: Measure,
) -> list[tuple[FloorRun, Window]]:
    """``m.windows`` pairs of a floor window and one of ours, in alternating order, after a
    discarded window of ours as warm-up."""
    session.window(m.warmup_s)
    out = []
    for i in range(m.windows):
        if i % 2 == 0:
            ours = session.window(m.window_s)
            floor = run_floor(pairs, pipeline, sgbm, n_floor, FLOOR_DECODE)
        else:
            floor = run_floor(pairs, pipeline, sgbm, n_floor, FLOOR_DECODE)
            ours = session.window(m.window_s)
        out.append((floor, ours))
    return out


def measure_config(
    vpc: RectifiedPairConfig,
    disp: int,
    *,
    stages: str,
    decode: bool | Literal["auto"],
    recording: Path,
    pairs: list[tuple[bytes, bytes]],
    rig: Any,
    tmp: Path,
    m: Measure,
    cpus: int,
    overrides: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """One row of the table: throughput (cameras unpaced) and latency (cameras paced) each in
    alternating windows with the floor, then the same-work loop ``m.repeat`` times."""
    stereo = StereoParams(**{"disparity_range": disp, **STAGES[stages], **(overrides or {})})
    pipeline = DepthPipeline(rig, vpc, stereo, cache_dir=tmp / "lut")
    sgbm = floor_matcher(stereo)
    check_floor_matcher(pairs, pipeline, sgbm)
    flags = FLOOR_DECODE
    # Size the floor's runs to about ours' windows and runs.
    probe = run_floor(pairs, pipeline, sgbm, 3, flags)
    n_window = max(5, int(m.window_s * probe.fps))
    n_same = max(5, int(m.seconds * run_same_work(pairs, pipeline, 3, flags).fps))

    def settings(pace: str | float) -> Settings:
        return bench_settings(recording, vpc, stereo, tmp / "lut", tmp, pace=pace, decode=decode)

    with WorkerSession(settings("fast")) as session:
        windows = alternate_windows(session, pairs, pipeline, sgbm, n_window, m)
    ours_fps = median(o.fps for _, o in windows)
    # Latency: cameras paced below capacity, so that a pair never waits behind another.
    pace = round(max(1.0, LATENCY_PACE_FRACTION * ours_fps), 2)
    with WorkerSession(settings(pace)) as session:
        paced = alternate_windows(session, pairs, pipeline, sgbm, n_window, m)
    sames = [run_same_work(pairs, pipeline, n_same, flags) for _ in range(m.repeat)]
    ratios = [o.fps / f.fps for f, o in windows]
    # The rate ours' CPU per frame allows with every core busy, against the floor's.
    ceilings = [cpus * 1e3 / o.cpu_ms / f.fps for f, o in windows]
    lat_ratios = [median(o.latency_ms) / median(f.frame_ms) for f, o in paced if o.latency_ms]
    same_fps = median(f.fps for f in sames)
    same_ms = median(median(f.frame_ms) for f in sames)
    latencies = [x for _, o in paced for x in o.latency_ms]
    stage_keys = paced[0][1].stage_ms if paced else {}
    return {
        "vpc": [pipeline.pair.camera.width, pipeline.pair.camera.height],
        "projection": pipeline.pair.projection,
        "px_per_deg": math.radians(pipeline.pair.fx),
        "disparities": disp,
        "stereo": stereo.model_dump(),
        "floor_ms_per_frame": median(median(f.frame_ms) for f, _ in windows),
        "floor_fps": median(f.fps for f, _ in windows),
        "same_work_ms_per_frame": same_ms,
        "same_work_fps": same_fps,
        "ours_fps": ours_fps,
        "throughput_ratio": median(ratios),
        "throughput_ratio_iqr": list(_quartiles(ratios)),
        "throughput_ratio_same_work": ours_fps / same_fps,
        "cpu_ceiling_ratio": median(ceilings),
        "latency_pace_fps": pace,
        "ours_latency_ms": summary(latencies),
        "latency_ratio": median(lat_ratios),
        "latency_ratio_iqr": list(_quartiles(lat_ratios)),
        "latency_ratio_same_work": median(latencies) / same_ms,
        "ours_stage_ms": {k: median(o.stage_ms.get(k, math.nan) for _, o in paced) for k in stage_keys},
        "floor_cpu_ms_per_frame": median(f.cpu_ms for f, _ in windows),
        "same_work_cpu_ms_per_frame": median(f.cpu_ms for f in sames),
        "ours_cpu_ms_per_frame": median(o.cpu_ms for _, o in windows),
        "floor_cores_busy": median(f.cpu_ms * f.fps / 1e3 for f, _ in windows),
        "ours_cores_busy": median(o.cores for _, o in windows),
        "worker_errors": sum(o.errors for _, o in windows + paced),
        "runs": {
            "floor_fps": [f.fps for f, _ in windows],
            "ours_fps": [o.fps for _, o in windows],
            "throughput_ratio": ratios,
            "cpu_ceiling_ratio": ceilings,
            "latency_floor_ms": [median(f.frame_ms) for f, _ in paced],
            "ours_latency_p50_ms": [median(o.latency_ms) for _, o in paced],
            "latency_ratio": lat_ratios,
            "same_work_fps": [f.fps for f in sames],
        },
    }


def _table_row(row: dict[str, Any]) -> list[str]:
    q1, q3 = row["throughput_ratio_iqr"]
    l1, l3 = row["latency_ratio_iqr"]
    lat = row["ours_latency_ms"]
    stage_text = " ".join(
        f"{k[:3]} {v:.1f}" for k, v in row["ours_stage_ms"].items() if k != "total" and not math.isnan(v)
    )
    return [
        _label(row),
        str(row["disparities"]),
        f"{row['floor_ms_per_frame']:.1f}",
        f"{row['floor_fps']:.1f}",
        f"{row['same_work_ms_per_frame']:.1f}",
        f"{row['ours_fps']:.1f}",
        f"{row['throughput_ratio']:.2f} ({q1:.2f}–{q3:.2f}) / {row['throughput_ratio_same_work']:.2f}",
        f"{row['cpu_ceiling_ratio']:.2f}",
        f"{lat['p50']:.1f} ({lat['p95']:.1f})",
        f"{row['latency_ratio']:.2f} ({l1:.2f}–{l3:.2f}) / {row['latency_ratio_same_work']:.2f}",
        f"{row['floor_cpu_ms_per_frame']:.1f} / {row['same_work_cpu_ms_per_frame']:.1f} / "
        f"{row['ours_cpu_ms_per_frame']:.1f}",
        f"{row['floor_cores_busy']:.2f} / {row['ours_cores_busy']:.2f}",
        stage_text,
    ]


TABLE_COLUMNS = (
    "VPC",
    "disp",
    "floor ms",
    "floor fps",
    "same-work ms",
    "ours fps",
    "throughput × floor (IQR) / same",
    "CPU ceiling × floor",
    "ours latency ms p50 (p95)",
    "latency × floor (IQR) / same",
    "CPU ms/frame floor / same / ours",
    "cores busy floor / ours",
    "ours stages ms (mean)",
)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m bench.worker", description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    parser.add_argument("--seconds", type=float, default=None, help="length of each same-work run")
    parser.add_argument(
        "--windows", type=int, default=None, help="floor / ours throughput window pairs per figure"
    )
    parser.add_argument("--window-seconds", type=float, default=None, help="length of each window")
    parser.add_argument(
        "--decode",
        choices=tuple(DECODE_MODES),
        default="auto",
        help="where frames are decoded (cameras.supervisor.decode): auto (the service's default: "
        "the camera threads while the worker waits for a pair, else the worker), capture (every "
        "frame in the camera threads) or worker (only the pairs the worker takes)",
    )
    parser.add_argument("--gray", action="store_true", help="gray JPEG frames instead of colour 4:2:2")
    parser.add_argument(
        "--stages",
        choices=("default", "floor"),
        default="default",
        help="ours with the service's default stages (subpixel refinement, confidence, 5×5 median) or "
        "with only the floor's work (plain SGBM: the pipelining and glue overhead alone)",
    )
    parser.add_argument(
        "--sizes",
        default=None,
        help="rectified pairs and disparities, e.g. 640x480/128,320x240/64 (pinhole pairs), latlon/128 "
        "(the lat-lon pair at its default resolution), latlon@4.5/128",
    )
    add_stereo_argument(parser)
    parser.add_argument(
        "--static",
        action="store_true",
        help="a static scene (one rig pose, fresh sensor noise every frame): the live service's temporal "
        "prior searches only what changes",
    )
    args = parser.parse_args(argv)
    quick = args.quick
    m = Measure(
        windows=args.windows or (2 if quick else 8),
        window_s=args.window_seconds or (0.5 if quick else 2.0),
        repeat=args.repeat or (1 if quick else 3),
        seconds=args.seconds or (1.0 if quick else 4.0),
        warmup_s=0.5 if quick else 1.5,
    )
    info = machine_info()
    print_machine(info, "worker path vs the bare OpenCV floor")
    spec = (
        MjpegSpec(frames=4, views=1, scale=0.25, color=not args.gray)
        if quick
        else MjpegSpec(views=1 if args.static else 2, color=not args.gray)
    )
    recording = ensure_mjpeg_recording(spec)
    pairs = load_jpeg_pairs(recording)
    rig = load_rig(recording / "calibration.yaml")
    configs = _configs(quick)
    if args.sizes:
        configs = [parse_config(item) for item in args.sizes.split(",")]
    kind = "colour 4:2:2" if spec.color else "gray"
    console.print(
        f"input: {recording} ({len(pairs)} pairs, {kind} JPEG q{spec.quality}, "
        f"{sum(len(a) + len(b) for a, b in pairs) / len(pairs) / 2 / 1024:.0f} KiB/frame); decode in "
        f"{args.decode}; throughput and latency: {m.windows} alternating window pairs of {m.window_s:g} s "
        f"each; same work: {m.repeat} run(s) of {m.seconds:g} s"
    )
    extra = f", {args.stereo}" if args.stereo else ""
    table = Table(
        title=f"per pair: floor (bare OpenCV) vs ours (service worker, {args.stages} stages{extra})"
    )
    for col in TABLE_COLUMNS:
        table.add_column(col, justify="right")
    rows = []
    with tempfile.TemporaryDirectory(prefix="rig-bench-worker-") as tmp_name:
        for vpc, disp in configs:
            row = measure_config(
                vpc,
                disp,
                stages=args.stages,
                decode=DECODE_MODES[args.decode],
                recording=recording,
                pairs=pairs,
                rig=rig,
                tmp=Path(tmp_name),
                m=m,
                cpus=info["cpus_usable"],
                overrides=stereo_overrides(args.stereo),
            )
            rows.append(row)
            table.add_row(*_table_row(row))
            if row["worker_errors"]:
                failed = row["worker_errors"]
                console.print(
                    f"[red]warning:[/red] the worker reported {failed} failed frame(s) at {_label(row)}"
                )
    console.print(
        "throughput × = ours fps / floor fps per window pair, median (interquartile range) (target ≥ 1.0, "
        "aim 1.3), and ours' median fps / the same-work loop's; CPU ceiling × = the fps ours' CPU per "
        "frame allows with every core busy / the floor's fps (no throughput × can pass it); latency × = "
        "ours p50 latency (arrival → published, unsaturated) / floor ms per frame per window pair, median "
        "(IQR) (target ≤ 1.2), and / "
        "the same-work loop's ms per frame"
    )
    return finish(
        "worker",
        info,
        {
            "recording": str(recording),
            "spec": spec.__dict__,
            "decode": args.decode,
            "stages": args.stages,
            "windows": m.windows,
            "window_seconds": m.window_s,
            "repeat": m.repeat,
            "seconds": m.seconds,
            "rows": rows,
        },
        args.json,
        table,
    )


if __name__ == "__main__":
    main()
