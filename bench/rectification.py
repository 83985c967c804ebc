"""Cost of the live rectification check (docs/rectification.md): what one check of
:class:`rig.rectification.monitor.RectificationMonitor` costs on the benchmark recording's
frames (the prototype's 1280×960 lenses, MJPEG decoded to gray), against the bare OpenCV call
it is built around: ``SIFT.detectAndCompute`` on both raw fisheye images (same feature cap).

Per figure the median of ``--repeat`` calls after a warm-up, interleaved call by call: wall time
and the process's CPU time (all threads: OpenCV runs parts of SIFT on its own pool), and the
duty cycle at the default ``check_interval_s``: CPU per check / interval, the share of one core
the monitor takes.

Then what it costs the depth worker: the service's runtime on the same recording (unpaced
cameras, 640×480 VPC, 128 disparities) in alternating windows with the monitor running at
``--interval`` seconds (shorter than the default, so its effect stands out of the noise) and
stopped (:class:`bench.alternating.WorkerSession`); the fps ratio per pair of windows and its
median. Run: ``.venv/bin/python -m bench.rectification`` (``--quick``: half-size, no worker
windows).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from rich.table import Table

from bench.alternating import WorkerSession
from bench.common import add_common_arguments, console, finish, machine_info, median, print_machine
from bench.recordings import MjpegSpec, ensure_mjpeg_recording, load_jpeg_pairs
from bench.worker import bench_settings
from rig.pipeline import DepthPipeline
from rig.rectification.monitor import RectificationConfig, RectificationMonitor
from rig.rectified import RectifiedPairConfig
from rig.sim import get_preset
from rig.stereo import StereoParams

__all__ = ["main"]

U8 = NDArray[np.uint8]


def _gray(data: bytes) -> U8:
    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_GRAYSCALE)
    return np.asarray(img, dtype=np.uint8)


def _timed(fn: Any) -> tuple[float, float, Any]:
    """(wall ms, process CPU ms, result) of one call."""
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return (time.perf_counter() - w0) * 1e3, (time.process_time() - c0) * 1e3, out


def worker_impact(recording: Path, interval_s: float, windows: int, seconds: float) -> dict[str, Any]:
    """Depth fps with the monitor running every ``interval_s`` against stopped, in alternating
    windows of one runtime (see the module doc)."""
    with tempfile.TemporaryDirectory(prefix="rig-bench-rect-") as tmp:
        settings = bench_settings(
            recording, RectifiedPairConfig(), StereoParams(disparity_range=128), Path(tmp) / "lut", Path(tmp),
            pace="fast", decode="auto",
        )  # fmt: skip
        settings = settings.model_copy(
            update={"rectification": RectificationConfig(check_interval_s=interval_s)}
        )
        on: list[float] = []
        off: list[float] = []
        checks: list[int] = []
        with WorkerSession(settings) as session:
            monitor = session.runtime.rectification
            assert monitor is not None
            monitor.stop()
            for i in range(windows):
                for running in (True, False) if i % 2 == 0 else (False, True):
                    if running:
                        before = monitor.status().checks
                        monitor.start()
                        on.append(session.window(seconds).fps)
                        monitor.stop()
                        checks.append(monitor.status().checks - before)
                    else:
                        off.append(session.window(seconds).fps)
    ratios = [a / b for a, b in zip(on, off, strict=True) if b > 0]
    return {"interval_s": interval_s, "fps_on": on, "fps_off": off, "ratios": ratios,
            "ratio": median(ratios), "checks_per_window": checks, "window_s": seconds}  # fmt: skip


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    parser.add_argument(
        "--interval", type=float, default=2.0, help="check interval in the worker windows (s)"
    )
    parser.add_argument(
        "--windows", type=int, default=None, help="pairs of worker windows (default 4; quick: 0)"
    )
    parser.add_argument("--window-s", type=float, default=10.0, help="seconds per worker window")
    args = parser.parse_args(argv)
    repeat = args.repeat or (2 if args.quick else 9)
    scale = 0.5 if args.quick else 1.0
    info = machine_info()
    print_machine(info, "rectification check: cost per check against bare SIFT on the fisheye pair")
    recording = ensure_mjpeg_recording(MjpegSpec(scale=scale))
    pairs = [(_gray(a), _gray(b)) for a, b in load_jpeg_pairs(recording)]
    rig = get_preset("prototype").scaled(scale).rig
    options = RectificationConfig()
    vpc = RectifiedPairConfig(width=320, height=240) if args.quick else RectifiedPairConfig()
    pipeline = DepthPipeline(rig, vpc)
    monitor = RectificationMonitor(lambda: pipeline.in_effect, lambda: None, options)
    sift = cv2.SIFT.create(nfeatures=options.max_features)

    def bare(left: U8, right: U8) -> int:
        return len(sift.detectAndCompute(left, None)[0]) + len(sift.detectAndCompute(right, None)[0])

    rows: dict[str, list[float]] = {
        k: [] for k in ("check_wall", "check_cpu", "sift_wall", "sift_cpu", "matches")
    }
    p50: list[float] = []
    t0 = time.perf_counter()
    monitor.check(*pairs[0])  # warm-up (OpenCV's pool, caches); builds the epipolar views
    setup_ms = (time.perf_counter() - t0) * 1e3
    bare(*pairs[0])
    for i in range(repeat):
        left, right = pairs[i % len(pairs)]
        wall, cpu, result = _timed(lambda left=left, right=right: monitor.check(left, right))
        rows["check_wall"].append(wall)
        rows["check_cpu"].append(cpu)
        rows["matches"].append(float(result.measure.count))
        if result.measure.p50_px is not None:
            p50.append(result.measure.p50_px)
        wall, cpu, _ = _timed(lambda left=left, right=right: bare(left, right))
        rows["sift_wall"].append(wall)
        rows["sift_cpu"].append(cpu)
    med = {k: median(v) for k, v in rows.items()}
    duty = med["check_cpu"] / (options.check_interval_s * 1e3)
    table = Table(title=f"one check, {pairs[0][0].shape[1]}x{pairs[0][0].shape[0]} fisheye pair, VPC "
                        f"{vpc.width}x{vpc.height}, median of {repeat}")  # fmt: skip
    for col in ("", "wall ms", "CPU ms (process)", "× bare SIFT (CPU)"):
        table.add_column(col, justify="right")
    table.add_row(
        "bare SIFT, both fisheye images", f"{med['sift_wall']:.0f}", f"{med['sift_cpu']:.0f}", "1.00"
    )
    table.add_row(
        "rectification check", f"{med['check_wall']:.0f}", f"{med['check_cpu']:.0f}",
        f"{med['check_cpu'] / med['sift_cpu']:.2f}",
    )  # fmt: skip
    console.print(
        f"first check (building the epipolar views too) {setup_ms:.0f} ms; matches in the VPC pair per check "
        f"{med['matches']:.0f}; vertical disparity p50 {median(p50):.3f} px (true calibration); "
        f"at check_interval_s {options.check_interval_s:g}: {100 * duty:.1f} % of one core"
    )
    impact: dict[str, Any] | None = None
    windows = args.windows if args.windows is not None else (0 if args.quick else 4)
    if windows:
        impact = worker_impact(recording, args.interval, windows, args.window_s)
        drop = 1.0 - impact["ratio"]
        console.print(
            f"depth worker (640x480, 128 disparities, unpaced): fps with the monitor checking every "
            f"{args.interval:g} s / without = {impact['ratio']:.3f} (median of "
            f"{len(impact['ratios'])} window pairs: {', '.join(f'{r:.3f}' for r in impact['ratios'])}; "
            f"{median([float(c) for c in impact['checks_per_window']]):.0f} checks per {args.window_s:g} s "
            "window); "
            f"scaled to check_interval_s {options.check_interval_s:g}: "
            f"{100 * drop * args.interval / options.check_interval_s:.2f} % fewer frames"
        )
    results = {
        "worker_impact": impact,
        "repeat": repeat,
        "scale": scale,
        "vpc": [vpc.width, vpc.height],
        "first_check_ms": setup_ms,
        "median_ms": med,
        "runs_ms": rows,
        "cpu_ratio_to_bare_sift": med["check_cpu"] / med["sift_cpu"],
        "duty_cycle_one_core": duty,
        "check_interval_s": options.check_interval_s,
        "p50_px": median(p50),
    }
    return finish("rectification", info, results, args.json, table)


if __name__ == "__main__":
    main()
