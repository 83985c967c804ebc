"""Wide (lat-lon) against pinhole rectified pairs: CPU per frame and per steradian of valid range.

Input: the MJPEG room recording of :mod:`bench.recordings` (the prototype's 1280×960 lenses),
decoded to gray once up front (decoding is the same work for every variant).

Variants (:func:`rig.evaluate.wide_pair.default_variants`): the default pinhole pair (640×480,
90°); a lat-lon pair with its pixel budget; a lat-lon pair with its angular resolution at the
centre (320 px/rad, the default lat-lon resolution); a pinhole with that lat-lon pair's budget
and the same centre resolution (wider, 992×744).

Per variant, alternating rounds of:

* **floor** — the bare OpenCV calls doing the matching work: ``cv2.remap`` ×2 with the
  pipeline's fixed-point maps and ``compute`` of a ``cv2.StereoSGBM`` with the same parameters;
* **ours** — :meth:`rig.pipeline.DepthPipeline.process` with the default stages (remap, matcher,
  speckle removal, subpixel refinement, confidence, 5×5 median, depth and range).

Printed: wall and process-CPU ms per frame (medians over rounds), the steradians of valid range
per frame (the solid angles of the valid pixels, :func:`rig.field.pixel_solid_angles`), CPU ms
per valid steradian, ours' throughput against its floor (floor ms / ours ms) and each variant's
CPU per valid steradian against the pinhole pair's.
Run: ``.venv/bin/python -m bench.wide_pair`` (``--quick`` for a run of seconds).
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from rich.table import Table

from bench.common import (
    add_common_arguments,
    add_stereo_argument,
    console,
    finish,
    machine_info,
    median,
    print_machine,
    stereo_overrides,
)
from bench.recordings import MjpegSpec, ensure_mjpeg_recording, load_jpeg_pairs
from bench.worker import floor_match
from calibration import load_rig
from rig.evaluate.wide_pair import REFERENCE_VARIANT, Variant, default_variants
from rig.field import pixel_solid_angles
from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoMatcher, StereoParams, create_opencv_matcher

__all__ = ["main", "measure_variant"]

U8 = NDArray[np.uint8]


def _timed(step: Callable[[int], Any], frames: int) -> tuple[float, float]:
    """Median wall ms per frame and process CPU ms per frame of ``step(i)`` for i < frames."""
    walls = []
    c0 = time.process_time()
    for i in range(frames):
        t0 = time.perf_counter()
        step(i)
        walls.append((time.perf_counter() - t0) * 1e3)
    return median(walls), (time.process_time() - c0) * 1e3 / frames


def measure_variant(
    variant: Variant,
    rig: Any,
    stereo: StereoParams,
    frames: list[tuple[U8, U8]],
    *,
    rounds: int,
    per_round: int,
    lut_dir: Path,
) -> dict[str, Any]:
    """One row: ``rounds`` alternating runs of the floor and ours, ``per_round`` frames each."""
    pipeline = DepthPipeline(rig, variant.vpc, stereo, cache_dir=lut_dir, tune_malloc=False)
    left_lut, right_lut = (pipeline.luts[n] for n in pipeline.names)
    sgbm = create_opencv_matcher(stereo)
    remap: Any = cv2.remap

    def floor(i: int) -> None:
        left, right = frames[i % len(frames)]
        lv = remap(left, left_lut.map1, left_lut.map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        rv = remap(right, right_lut.map1, right_lut.map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        floor_match(sgbm, lv, rv, stereo.lr_check)

    valid_sr: list[float] = []
    solid = pixel_solid_angles(pipeline.pair.camera)

    def ours(i: int) -> None:
        left, right = frames[i % len(frames)]
        frame = pipeline.process(left, right)
        if len(valid_sr) < len(frames):
            valid_sr.append(float(solid[frame.valid].sum()))

    # The floor's matcher is the pipeline's (same parameters: same raw disparity).
    lv, rv = pipeline.remap(*frames[0])
    if not np.array_equal(StereoMatcher(stereo).raw(lv, rv), sgbm.compute(lv, rv)):
        raise SystemExit("the floor's matcher differs from the pipeline's: not the same parameters")
    floor(0)
    ours(0)
    f_runs: list[tuple[float, float]] = []
    o_runs: list[tuple[float, float]] = []
    for k in range(rounds):
        first, second = (floor, ours) if k % 2 == 0 else (ours, floor)
        a, b = _timed(first, per_round), _timed(second, per_round)
        (f_runs, o_runs)[k % 2].append(a)
        (o_runs, f_runs)[k % 2].append(b)
    cam = pipeline.pair.camera
    sr = median(valid_sr)
    out: dict[str, Any] = {
        "variant": variant.name,
        "label": variant.label,
        "projection": pipeline.pair.projection,
        "size": [cam.width, cam.height],
        "pixels": cam.width * cam.height,
        "px_per_deg_centre": float(np.radians(cam.fx)),
        "disparities": stereo.disparity_range,
        "floor_ms": median(w for w, _ in f_runs),
        "floor_cpu_ms": median(c for _, c in f_runs),
        "ours_ms": median(w for w, _ in o_runs),
        "ours_cpu_ms": median(c for _, c in o_runs),
        "valid_sr": sr,
    }
    out["throughput_vs_floor"] = out["floor_ms"] / out["ours_ms"]
    out["ours_cpu_ms_per_sr"] = out["ours_cpu_ms"] / sr
    out["floor_cpu_ms_per_sr"] = out["floor_cpu_ms"] / sr
    out["runs"] = {"floor": f_runs, "ours": o_runs}
    return out


TABLE_COLUMNS = (
    "variant",
    "size (pixels)",
    "px/deg",
    "valid sr",
    "floor ms (CPU)",
    "ours ms (CPU)",
    "throughput × floor",
    "CPU ms / valid sr: floor / ours",
    "ours CPU / sr × pinhole's",
)


def _row(r: dict[str, Any], ref: dict[str, Any]) -> list[str]:
    w, h = r["size"]
    return [
        r["label"],
        f"{w}×{h} ({r['pixels'] / 1e3:.0f}k)",
        f"{r['px_per_deg_centre']:.2f}",
        f"{r['valid_sr']:.2f}",
        f"{r['floor_ms']:.1f} ({r['floor_cpu_ms']:.1f})",
        f"{r['ours_ms']:.1f} ({r['ours_cpu_ms']:.1f})",
        f"{r['throughput_vs_floor']:.2f}",
        f"{r['floor_cpu_ms_per_sr']:.1f} / {r['ours_cpu_ms_per_sr']:.1f}",
        f"{r['ours_cpu_ms_per_sr'] / ref['ours_cpu_ms_per_sr']:.2f}",
    ]


def _decode(pairs: list[tuple[bytes, bytes]]) -> list[tuple[U8, U8]]:
    def gray(b: bytes) -> U8:
        return np.asarray(cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_GRAYSCALE), dtype=np.uint8)

    return [(gray(a), gray(b)) for a, b in pairs]


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m bench.wide_pair", description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    parser.add_argument("--frames", type=int, default=None, help="frames per round of each side")
    add_stereo_argument(parser)
    args = parser.parse_args(argv)
    quick = args.quick
    rounds = args.repeat or (2 if quick else 6)
    per_round = args.frames or (2 if quick else 8)
    logging.getLogger("rig.pipeline").setLevel(logging.ERROR)  # "the VPC leaves the lens" notes
    info = machine_info()
    print_machine(info, "wide (lat-lon) vs pinhole pairs: CPU per frame and per steradian of valid range")
    spec = MjpegSpec(frames=4, views=1, scale=0.25) if quick else MjpegSpec()
    recording = ensure_mjpeg_recording(spec)
    frames = _decode(load_jpeg_pairs(recording))
    rig = load_rig(recording / "calibration.yaml")
    overrides = stereo_overrides(args.stereo)
    stereo = StereoParams(**({"disparity_range": 32} if quick else {}), **overrides)
    pinhole = (
        RectifiedPairConfig(width=160, height=120) if quick else RectifiedPairConfig(projection="pinhole")
    )
    variants = default_variants(rig, stereo, pinhole, ())
    console.print(
        f"input: {recording} ({len(frames)} pairs decoded to gray up front); {rounds} alternating "
        f"rounds of {per_round} frames per side and variant; stereo defaults"
        f"{', ' + args.stereo if args.stereo else ''}, {stereo.disparity_range} disparities"
    )
    rows = []
    with tempfile.TemporaryDirectory(prefix="rig-bench-wide-") as tmp:
        for v in variants:
            rows.append(
                measure_variant(v, rig, stereo, frames, rounds=rounds, per_round=per_round, lut_dir=Path(tmp))
            )
    ref = next(r for r in rows if r["variant"] == REFERENCE_VARIANT)
    table = Table(title="floor: remap ×2 + StereoSGBM.compute; ours: DepthPipeline.process (default stages)")
    for col in TABLE_COLUMNS:
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(*_row(r, ref))
    console.print(
        "throughput × floor = floor ms / ours ms (≥ 1.0: ours keeps up with the bare calls); CPU ms / "
        "valid sr = process CPU per frame / steradians of valid range per frame; the last column "
        "against the pinhole pair"
    )
    return finish(
        "wide_pair",
        info,
        {"recording": str(recording), "rounds": rounds, "per_round": per_round, "rows": rows},
        args.json,
        table,
    )


if __name__ == "__main__":
    main()
