"""LUT build per camera model against ``cv2.fisheye.initUndistortRectifyMap`` (docs/performance.md,
"LUT build per model").

Grid: the pinhole VPC (640×480, 90° horizontal FOV) of the prototype rig's left camera
(1280×960 Kannala-Brandt 190°, rotated 45° off the lens axis, as the service builds it). Every
other model is the prototype lens converted to that model (least squares over the lens's field,
:func:`calibration.initial_guess.convert_model`); the pinhole (which cannot see a fisheye's field) is fitted
over 60° and the VPC grid is the same.

What is timed:

* **OpenCV** — ``cv2.fisheye.initUndistortRectifyMap(K, D, R, P, (640, 480), cv2.CV_16SC2)`` with
  the prototype's K and D (k1..k4), ``R = R_cam_rect^T`` and ``P`` = the VPC's K: the fixed-point
  map pair (CV_16SC2 + CV_16UC1) OpenCV's own remap uses. (OpenCV cannot follow rays past 90°;
  it maps those pixels nowhere, which does not make it slower.)
* **ours, cold** — :func:`rig.lut.build_rectified_lut`: the same fixed-point maps plus the float maps
  and the validity mask, rays followed up to the lens limit, for any model.
* **ours, warm** — :meth:`rig.lut_cache.LutCache.load` of the stored table: read, checksum over
  the whole payload, and the arrays (what a service start with a warm cache costs per camera).

Wall and process CPU time are both reported (both sides run on one thread, so on a shared
machine the CPU-time ratio is the steadier one). Each figure is the median of ``--repeat`` timed
calls after a warm-up call; OpenCV and ours are interleaved call by call. The process's malloc is
tuned as the service's is (:func:`rig.pipeline.tune_allocator`).
Run: ``.venv/bin/python -m bench.lut_build`` (``--quick``).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from rich.table import Table

from bench.common import add_common_arguments, console, finish, machine_info, median, print_machine
from calibration.initial_guess import convert_model, seed_model
from calibration.models import MODELS, CameraModel, KannalaBrandtModel, PinholeModel
from rig.lut import build_rectified_lut
from rig.lut_cache import LutCache, lut_key
from rig.pipeline import tune_allocator
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from rig.sim import get_preset

__all__ = ["fitted_models", "main"]

FIT_FIELD_DEG = 95.0
PINHOLE_FIELD_DEG = 60.0


def fitted_models(lens: KannalaBrandtModel) -> dict[str, CameraModel]:
    """Every registered model, fitted to ``lens`` (the lens itself for kannala_brandt)."""
    out: dict[str, CameraModel] = {}
    for name in sorted(MODELS):
        if name == lens.name:
            out[name] = lens
            continue
        field = math.radians(PINHOLE_FIELD_DEG if name == "pinhole" else FIT_FIELD_DEG)
        model = convert_model(lens, seed_model(name, lens, field), field)
        if name != "pinhole":
            model = model.replace(fov_deg=lens.fov_deg)
        out[name] = model
    return out


def _interleaved(fns: dict[str, Any], repeat: int) -> dict[str, dict[str, list[float]]]:
    """Wall and process CPU time (ms) of each function, calls interleaved. Both sides are
    single-threaded, so CPU time is the load-robust figure on a shared machine."""
    for fn in fns.values():
        fn()
    out: dict[str, dict[str, list[float]]] = {k: {"wall": [], "cpu": []} for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            out[k]["wall"].append((time.perf_counter() - t0) * 1e3)
            out[k]["cpu"].append((time.process_time() - c0) * 1e3)
    return out


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m bench.lut_build", description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    parser.add_argument("--models", default=None, help="comma-separated model names (default: all)")
    args = parser.parse_args(argv)
    repeat = args.repeat or (3 if args.quick else 15)
    tuned = tune_allocator()  # as the service runs (DepthPipeline does it)
    info = machine_info()
    print_machine(info, "VPC LUT build per model vs cv2.fisheye.initUndistortRectifyMap")
    preset = get_preset("prototype")
    pair_cfg = (
        RectifiedPairConfig(width=160, height=120)
        if args.quick
        else RectifiedPairConfig(projection="pinhole")
    )
    pair = design_rectified_pair(preset.rig, pair_cfg)
    lens = preset.rig.cameras[pair.left]
    if not isinstance(lens, KannalaBrandtModel):
        raise SystemExit("the prototype preset's lens is expected to be Kannala-Brandt")
    R = pair.R_cam_rect[pair.left]
    vpc = pair.camera
    if not isinstance(vpc, PinholeModel):
        raise SystemExit("OpenCV's fisheye map is a pinhole view's: the benchmark needs the pinhole pair")
    K = np.array([[lens.fx, 0.0, lens.cx], [0.0, lens.fy, lens.cy], [0.0, 0.0, 1.0]])
    D = np.array(lens.k, dtype=np.float64)
    size = (vpc.width, vpc.height)

    def opencv() -> Any:
        return cv2.fisheye.initUndistortRectifyMap(K, D, R.T, vpc.K, size, cv2.CV_16SC2)

    models = fitted_models(lens)
    if args.models:
        wanted = [m.strip() for m in args.models.split(",")]
        unknown = sorted(set(wanted) - set(models))
        if unknown:
            raise SystemExit(f"unknown model(s) {', '.join(unknown)}; known: {', '.join(models)}")
        models = {k: v for k, v in models.items() if k in wanted}
    console.print(
        f"grid: VPC {vpc.width}×{vpc.height} (hfov {pair_cfg.hfov_deg:g}°), prototype left lens "
        f"{lens.width}×{lens.height} rotated {math.degrees(math.acos((np.trace(R) - 1) / 2)):.1f}° off its "
        f"axis; {repeat} timed calls per figure (median); malloc tuned as in the service: {tuned}"
    )
    table = Table(title="LUT build, ms (median) and ratio to OpenCV's KB map in the same run")
    for col in (
        "model",
        "OpenCV ms",
        "ours cold ms",
        "cold ×",
        "CPU ms OpenCV / ours",
        "cold × (CPU)",
        "ours warm ms",
        "valid %",
    ):
        table.add_column(col, justify="right")
    rows = []
    with tempfile.TemporaryDirectory(prefix="rig-bench-lut-") as tmp:
        cache = LutCache(Path(tmp))
        for name, model in models.items():
            key = lut_key(model, R, vpc)
            built = build_rectified_lut(model, R, vpc)
            cache.store(key, built)

            def cold(m: CameraModel = model) -> Any:
                return build_rectified_lut(m, R, vpc)

            def warm(k: str = key) -> Any:
                lut = cache.load(k, (vpc.height, vpc.width))
                if lut is None:
                    raise SystemExit(f"the cache lost table {k}")
                return lut

            times = _interleaved({"opencv": opencv, "cold": cold, "warm": warm}, repeat)
            wall = {k: median(v["wall"]) for k, v in times.items()}
            cpu = {k: median(v["cpu"]) for k, v in times.items()}
            row = {
                "model": name,
                "params": model.to_dict(),
                "opencv_ms": wall["opencv"],
                "cold_ms": wall["cold"],
                "warm_ms": wall["warm"],
                "cold_ratio": wall["cold"] / wall["opencv"],
                "warm_ratio": wall["warm"] / wall["opencv"],
                "cpu_ms": cpu,
                "cold_ratio_cpu": cpu["cold"] / cpu["opencv"],
                "valid_fraction": built.valid_fraction,
                "runs": times,
            }
            rows.append(row)
            table.add_row(
                name,
                f"{wall['opencv']:.2f}",
                f"{wall['cold']:.2f}",
                f"{wall['cold'] / wall['opencv']:.2f}",
                f"{cpu['opencv']:.2f} / {cpu['cold']:.2f}",
                f"{cpu['cold'] / cpu['opencv']:.2f}",
                f"{wall['warm']:.2f}",
                f"{100 * built.valid_fraction:.1f}",
            )
    console.print(
        "targets: kannala_brandt cold ≤ 1.0× OpenCV, every model ≤ 3×, warm (cache load) ≤ 5 ms per table"
    )
    return finish(
        "lut_build",
        info,
        {"vpc": [vpc.width, vpc.height], "repeat": repeat, "rows": rows},
        args.json,
        table,
    )


if __name__ == "__main__":
    main()
