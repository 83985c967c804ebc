"""The coarse-to-fine search's parts and the alternatives it was chosen over, in CPU per frame
against the exact search (docs/stereo.md, "Coarse-to-fine search").

Input: the MJPEG room recording of :mod:`bench.recordings`, remapped to the rectified pair
(``--projection``: the default lat-lon pair or the 640×480 pinhole pair) up front. Per row, the
process CPU time of one call per frame (every thread), median over ``--repeat`` rounds of every
frame, and its ratio to the exact search's in the same round:

* **exact search**: :meth:`rig.stereo.StereoMatcher.compute` with ``coarse_to_fine: false`` and
  ``lr_check_scale: 1`` (SGBM over the whole range at full resolution, twice for the left-right
  check: the default before the check went to half resolution);
* **the default**: the same call with the defaults (the left view as the exact search's, the
  left-right check's second run at half resolution, :mod:`rig.half_check`);
* **coarse-to-fine search**: the same call with the defaults; its **coarse level** alone (the
  two views' SGBM at 1/2 resolution) and the **fine level** (the rest: the images' contrast
  normalisation, which the refinement after it reuses, and the band search of both views);
* the same with ``coarse_confirm`` (its coarse level twice);
* the alternatives, each one SGBM call (one view) in full: SGBM at full resolution over a
  narrow window (16 and 32 disparities: what a band around the coarse answer would cost if
  OpenCV matched it), the same window tile by tile (64×64 tiles with their margins and the
  window's reach), and the coarse levels at 1/2 and 1/4 (48 and 32 disparities);
* the range: the default and the coarse-to-fine search with 256 disparities (the lat-lon pair's
  field widened by the larger unmatched band: its lookup tables are built for it), to set against
  the same searches with 96.

Run: ``flock /tmp/rig-bench.lock .venv/bin/python -m bench.coarse_to_fine`` (``--quick``: seconds).
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

from bench.common import add_common_arguments, finish, machine_info, median, print_machine
from bench.recordings import MjpegSpec, ensure_mjpeg_recording, load_jpeg_pairs
from calibration import load_rig
from rig.coarse_to_fine import downsample
from rig.pipeline import DepthPipeline
from rig.postprocess import refine_pool
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoMatcher, StereoParams, create_opencv_matcher

__all__ = ["main"]

U8 = NDArray[np.uint8]
Pair = tuple[U8, U8]
TILE = 64
EXACT = "exact search, check at full resolution (both views)"
DEFAULT = "the default: exact left view, check at half resolution"
C2F = "coarse-to-fine search (both views)"
COARSE = "  its coarse level (both views)"
FINE = "  its fine level and normalisation (the rest)"
CONFIRMED = "coarse-to-fine search, coarse_confirm (both views)"


def _rectified(recording: Path, vpc: RectifiedPairConfig, stereo: StereoParams, lut: Path) -> list[Pair]:
    pipe = DepthPipeline(
        load_rig(recording / "calibration.yaml"), vpc, stereo, cache_dir=lut, tune_malloc=False
    )
    out = []
    for a, b in load_jpeg_pairs(recording):
        left, right = (
            np.asarray(cv2.imdecode(np.frombuffer(x, np.uint8), cv2.IMREAD_GRAYSCALE), dtype=np.uint8)
            for x in (a, b)
        )
        out.append(pipe.remap(left, right))
    return out


def _sgbm(disparities: int, scale: int = 1, tiles: bool = False) -> Callable[[Pair], object]:
    """One SGBM view over ``disparities`` at 1/``scale`` resolution (whole image or tiles)."""
    sgbm = create_opencv_matcher(
        StereoParams(disparity_range=disparities, speckle_size=0, coarse_to_fine=False)
    )
    margin = 7 // 2 + 1

    def whole(pair: Pair) -> object:
        left, right = (downsample(img, scale) if scale > 1 else img for img in pair)
        return sgbm.compute(left, right)

    def tiled(pair: Pair) -> object:
        left, right = pair
        h, w = left.shape
        for y in range(0, h, TILE):
            for x in range(disparities, w, TILE):
                y0, y1 = max(0, y - margin), min(h, y + TILE + margin)
                x0, x1 = max(0, x - disparities - margin), min(w, x + TILE + margin)
                sgbm.compute(left[y0:y1, x0:x1], right[y0:y1, x0:x1])
        return None

    return tiled if tiles else whole


Row = tuple[Callable[[Pair], object], list[Pair]]


def _rows(pairs: list[Pair], wide: list[Pair] | None, quick: bool) -> dict[str, Row]:
    """Each measured call and the frames it runs on."""
    d = 32 if quick else 96
    exact = StereoMatcher(StereoParams(disparity_range=d, coarse_to_fine=False, lr_check_scale=1))
    default = StereoMatcher(StereoParams(disparity_range=d))
    c2f = StereoMatcher(StereoParams(disparity_range=d, coarse_to_fine=True))
    confirmed = StereoMatcher(StereoParams(disparity_range=d, coarse_to_fine=True, coarse_confirm=True))
    search = c2f.coarse_to_fine_search
    assert search is not None
    pool = refine_pool()
    quarter = max(16, (d // 4 + 15) // 16 * 16)

    def coarse(pair: Pair) -> object:
        return search.coarse_search(downsample(pair[0], 2), downsample(pair[1], 2), None, pool)

    rows: dict[str, Row] = {
        EXACT: (lambda p: exact.compute(*p), pairs),
        DEFAULT: (lambda p: default.compute(*p), pairs),
        C2F: (lambda p: c2f.compute(*p, pool=pool), pairs),
        COARSE: (coarse, pairs),
        # (its second coarse search on the same images: the CPU of one on the unnormalised pair)
        CONFIRMED: (lambda p: confirmed.compute(*p, pool=pool, unnormalised=p), pairs),
        "SGBM full resolution, 16 disparities (one view)": (_sgbm(16), pairs),
        "SGBM full resolution, 32 disparities (one view)": (_sgbm(32), pairs),
        f"SGBM {TILE}×{TILE} tiles, 16 disparities (one view)": (_sgbm(16, tiles=True), pairs),
        f"SGBM 1/2 resolution, {d // 2} disparities (one view)": (_sgbm(d // 2, 2), pairs),
        f"SGBM 1/4 resolution, {quarter} disparities (one view)": (_sgbm(quarter, 4), pairs),
    }
    if wide is not None:
        default_256 = StereoMatcher(StereoParams(disparity_range=256))
        rows["the default, 256 disparities (its own wider field)"] = (lambda p: default_256.compute(*p), wide)
        c2f_256 = StereoMatcher(StereoParams(disparity_range=256, coarse_to_fine=True))
        rows["coarse-to-fine search, 256 disparities (its own wider field)"] = (
            lambda p: c2f_256.compute(*p, pool=pool),
            wide,
        )
    return rows


def _cpu_ms(step: Callable[[Pair], object], pairs: list[Pair]) -> float:
    """Process CPU ms per frame of ``step`` over ``pairs`` (after one untimed call)."""
    step(pairs[0])
    c0 = time.process_time()
    for pair in pairs:
        step(pair)
    return (time.process_time() - c0) * 1e3 / len(pairs)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(
        prog="python -m bench.coarse_to_fine", description=__doc__.split("\n\n")[0]
    )
    add_common_arguments(parser)
    parser.add_argument("--projection", choices=("latlon", "pinhole"), default="latlon")
    args = parser.parse_args(argv)
    quick = args.quick
    rounds = args.repeat or (1 if quick else 5)
    logging.getLogger("rig.pipeline").setLevel(logging.ERROR)
    info = machine_info()
    print_machine(info, "the coarse-to-fine search's parts and alternatives, CPU per frame")
    spec = MjpegSpec(frames=4, views=1, scale=0.25) if quick else MjpegSpec()
    recording = ensure_mjpeg_recording(spec)
    if args.projection == "latlon":
        vpc = RectifiedPairConfig(px_per_deg=1.5) if quick else RectifiedPairConfig()
    else:
        vpc = (
            RectifiedPairConfig(width=160, height=120) if quick else RectifiedPairConfig(projection="pinhole")
        )
    with tempfile.TemporaryDirectory(prefix="rig-bench-c2f-") as tmp:
        pairs = _rectified(recording, vpc, StereoParams(disparity_range=32 if quick else 96), Path(tmp))
        # The 256 disparities' own pair: a lat-lon field widened by the larger unmatched band.
        wide = None if quick else _rectified(recording, vpc, StereoParams(disparity_range=256), Path(tmp))
    rows = _rows(pairs, wide, quick)
    runs: dict[str, list[float]] = {k: [] for k in rows}
    for _ in range(rounds):
        for name, (step, frames) in rows.items():
            runs[name].append(_cpu_ms(step, frames))
    runs = {**{k: v for k, v in runs.items() if k != COARSE}, COARSE: runs[COARSE]}
    runs[FINE] = [a - b for a, b in zip(runs[C2F], runs[COARSE], strict=True)]
    order = [EXACT, C2F, COARSE, FINE, *(k for k in rows if k not in (EXACT, C2F, COARSE))]
    ratios = {k: [a / b for a, b in zip(runs[k], runs[EXACT], strict=True)] for k in order}
    h, w = pairs[0][0].shape
    table = Table(title=f"{args.projection} pair {w}×{h}: process CPU ms per frame, × the exact search's")
    for col in ("call", "CPU ms", "× exact (range)"):
        table.add_column(col, justify="right")
    results = []
    for k in order:
        r = ratios[k]
        table.add_row(k, f"{median(runs[k]):.1f}", f"{median(r):.2f} ({min(r):.2f}–{max(r):.2f})")
        results.append({"call": k, "cpu_ms": median(runs[k]), "ratio": median(r), "ratios": r})
    return finish(
        "coarse_to_fine",
        info,
        {"projection": args.projection, "size": [w, h], "rounds": rounds, "rows": results},
        args.json,
        table,
    )


if __name__ == "__main__":
    main()
