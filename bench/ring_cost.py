"""What a ring of N cameras costs (docs/ring.md, "Cost"): its stereo pairs and its panorama
against N × the bare OpenCV calls of a pair, on the same frames.

Input: ring4 (four prototype lenses at 90°, 1280×960) rendered in the demo room
(:func:`rig.sim.ring_recording.simulate_ring_recording`, kept in the bench cache), the sets read
from its PNG files into memory once; ``--real`` takes the real ring of ``$RIG_SHARED_DATA``
(1600×1532) instead.

**Floor** — per set, in a plain loop, the bare OpenCV calls of every pair: ``cv2.imdecode`` of each
camera once (to gray), then per pair ``cv2.remap`` ×2 with the pair's own fixed-point maps and
``compute`` of a ``cv2.StereoSGBM`` of the same parameters (and its mirrored run for the left-right
check): N × a pair's floor (``bench.worker``'s), each camera decoded once.

**Pairs, one after the other** — the same frames decoded, then each pair's
:meth:`DepthPipeline.process` (every default stage: refinement, confidence, median), in a plain
loop: what N pairs cost without the panorama.

**Panorama** — :meth:`RigPipeline.fuse` of one set's pairs (the fusion alone).

**Ours** — the whole set on the one staged executor (:func:`rig.rig_depth.process_sets` over the
recording, PNG decode included, the panorama fused on the writer stage, a sink that keeps
nothing): sets/s and pairs/s.

Ratios are of one run, taken one right after another on a shared machine (the load average is
printed). The memory budget of the ring (:func:`service.memory.ring_estimate`) is printed
beside the measured peak of the fusion's arrays (tracemalloc) and the process's peak RSS.
Run: ``.venv/bin/python -m bench.ring_cost`` (``--quick``: the tests' small ring,
:func:`tests.helpers.rings.write_small_ring`, two sets: seconds; ``--panorama-px-per-deg``: another
panorama resolution, the service's ``panorama.px_per_deg``).
"""

from __future__ import annotations

import argparse
import os
import resource
import time
import tracemalloc
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from rich.table import Table

from bench.common import add_common_arguments, bench_cache_dir, console, finish, machine_info, print_machine
from bench.worker import floor_match, floor_matcher
from calibration import load_rig
from rig.memory_budget import MIB
from rig.panorama import DEFAULT_PANORAMA_PX_PER_DEG
from rig.recording import Recording
from rig.rectified import RectifiedPairConfig
from rig.rig_depth import process_sets, read_set_images
from rig.rig_pipeline import RigPipeline
from rig.sim.presets import get_ring_preset
from rig.sim.ring_recording import simulate_ring_recording
from service.memory import ring_estimate
from service.settings import Settings
from tests.helpers.ring import RING_DIR, load_ring, write_ring_recording
from tests.helpers.rings import SMALL_RING_CONFIG, SMALL_RING_PANORAMA_PX_PER_DEG, write_small_ring

__all__ = ["main"]

U8 = NDArray[np.uint8]


def _recording(quick: bool, real: bool) -> Path:
    """The ring recording of the run (made once into the bench cache)."""
    if real:
        shared = Path(
            os.environ.get("RIG_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")
        )
        out = bench_cache_dir() / "ring-real"
        if not (out / "frames.csv").is_file():
            write_ring_recording(load_ring(shared / RING_DIR), out)
        return out
    out = bench_cache_dir() / ("ring4-small" if quick else "ring4")
    if not (out / "frames.csv").is_file():
        if quick:  # the tests' small ring
            write_small_ring(out, frames=2)
        else:
            preset = get_ring_preset("ring4")  # the ideal lens and simple sensor model, as measured
            simulate_ring_recording(
                preset, out, frames=3, supersample=1, lens="ideal",
                noise_std=preset.noise_std, vignetting=preset.vignetting,
            )  # fmt: skip
    return out


def _encoded(rec: Recording, cameras: list[str]) -> list[dict[str, bytes]]:
    return [{c: rec.read_bytes(row, c) for c in cameras} for row in rec.pairs]


def _floor(sets: list[dict[str, bytes]], ring: RigPipeline, repeat: int) -> list[float]:
    """ms per set of the bare calls (module doc)."""
    decode: Any = cv2.imdecode
    remap: Any = cv2.remap
    matchers = {label: floor_matcher(p.stereo) for label, p in ring.pipelines.items()}
    maps = {label: [(p.luts[n].map1, p.luts[n].map2) for n in p.names] for label, p in ring.pipelines.items()}
    lr = {label: p.stereo.lr_check for label, p in ring.pipelines.items()}
    buffers = [{c: np.frombuffer(b, np.uint8) for c, b in s.items()} for s in sets]
    times = []
    for i in range(repeat * len(sets)):
        t0 = time.perf_counter()
        images = {c: decode(b, cv2.IMREAD_GRAYSCALE) for c, b in buffers[i % len(sets)].items()}
        for label, p in ring.pipelines.items():
            (l1, l2), (r1, r2) = maps[label]
            left = remap(images[p.names[0]], l1, l2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            right = remap(images[p.names[1]], r1, r2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            floor_match(matchers[label], left, right, lr[label])
        times.append((time.perf_counter() - t0) * 1e3)
    return times


def _pairs(sets: list[dict[str, bytes]], ring: RigPipeline, repeat: int) -> tuple[list[float], list[Any]]:
    """ms per set of every pair's DepthPipeline.process, and the last set's frames by pair."""
    times, frames = [], []
    for i in range(repeat * len(sets)):
        encoded = sets[i % len(sets)]
        t0 = time.perf_counter()
        images = {c: _gray(b) for c, b in encoded.items()}
        out = {
            label: p.process(images[p.names[0]], images[p.names[1]]) for label, p in ring.pipelines.items()
        }
        times.append((time.perf_counter() - t0) * 1e3)
        frames.append(out)
    return times, frames[-len(sets) :]


def _gray(data: bytes) -> U8:
    return np.asarray(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE), dtype=np.uint8)


def _fuse(ring: RigPipeline, frames: list[Any], repeat: int) -> tuple[list[float], int]:
    """ms per panorama, and the fusion's peak of traced memory (bytes)."""
    ring.fuse(frames[0])  # the rays and far-field pixels, made once
    times = []
    for i in range(repeat * len(frames)):
        t0 = time.perf_counter()
        ring.fuse(frames[i % len(frames)])
        times.append((time.perf_counter() - t0) * 1e3)
    tracemalloc.start()
    ring.fuse(frames[0])
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return times, peak


def _ours(rec: Recording, ring: RigPipeline, repeat: int) -> float:
    """Sets per second on the staged executor (module doc)."""
    rows = list(rec.pairs) * repeat
    # Every repeat of a row gets its own seq: the executor's sets are told apart by seq.
    renumbered = [type(row)(k, row.cameras, row.stamps, row.files) for k, row in enumerate(rows)]
    t0 = time.perf_counter()
    result = process_sets(ring, rec, renumbered, lambda _s, _f: None)
    elapsed = time.perf_counter() - t0
    if result.failures:
        raise SystemExit(f"ring bench: {len(result.failures)} sets failed: {result.failures[0].reason}")
    return result.written / elapsed


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m bench.ring_cost", description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    parser.add_argument("--real", action="store_true", help="the real ring of $RIG_SHARED_DATA")
    parser.add_argument(
        "--panorama-px-per-deg",
        type=float,
        default=None,
        help=f"the panorama's resolution (default {DEFAULT_PANORAMA_PX_PER_DEG:g}; --quick: "
        f"{SMALL_RING_PANORAMA_PX_PER_DEG:g}): the service's panorama.px_per_deg",
    )
    args = parser.parse_args(argv)
    repeat = args.repeat or (1 if args.quick else 3)
    info = machine_info()
    print_machine(info, "A ring of N cameras: its pairs and panorama against N x the bare OpenCV calls")
    path = _recording(args.quick, args.real)
    rec = Recording(path)
    rig = load_rig(path / "calibration.yaml")
    config = SMALL_RING_CONFIG if args.quick else RectifiedPairConfig()
    panorama_px_per_deg = args.panorama_px_per_deg
    if panorama_px_per_deg is None:
        panorama_px_per_deg = SMALL_RING_PANORAMA_PX_PER_DEG if args.quick else DEFAULT_PANORAMA_PX_PER_DEG
    ring = RigPipeline(rig, config, tune_malloc=True, panorama_px_per_deg=panorama_px_per_deg)
    pair = ring.first.pair.camera
    pano = ring.panorama.camera
    console.print(
        f"input: {path} ({len(rec.pairs)} sets of {len(rig.names)} cameras "
        f"{rig.cameras[rig.names[0]].width}x{rig.cameras[rig.names[0]].height}); {len(ring.pipelines)} pairs "
        f"{pair.width}x{pair.height}, panorama {pano.width}x{pano.height}; {repeat} passes per figure"
    )
    sets = _encoded(rec, ring.cameras)
    check = read_set_images(rec, rec.pairs[0], rig, ring.cameras)  # sizes checked once
    assert all(img.dtype == np.uint8 for img in check.values())
    floor = _floor(sets, ring, repeat)
    pairs_ms, frames = _pairs(sets, ring, repeat)
    fuse_ms, fuse_peak = _fuse(ring, frames, repeat)
    ours_sets = _ours(rec, ring, repeat)
    n = len(ring.pipelines)
    floor_set = float(np.median(floor))
    results = {
        "cameras": len(rig.names),
        "pairs": n,
        "pair_size": [pair.width, pair.height],
        "panorama_size": [pano.width, pano.height],
        "floor_ms_per_set": floor_set,
        "floor_pairs_per_s": n * 1e3 / floor_set,
        "pairs_ms_per_set": float(np.median(pairs_ms)),
        "pairs_per_s_one_after_the_other": n * 1e3 / float(np.median(pairs_ms)),
        "panorama_ms": float(np.median(fuse_ms)),
        "panorama_frames_per_s": 1e3 / float(np.median(fuse_ms)),
        "ours_sets_per_s": ours_sets,
        "ours_pairs_per_s": ours_sets * n,
        "fusion_peak_traced_bytes": fuse_peak,
        "peak_rss_bytes": (peak_rss := resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024),
    }
    budget = ring_estimate(
        Settings(),
        rig,
        [p.pair for p in ring.pipelines.values()],
        ring.first.stereo,
        (pano.width, pano.height),
    )
    results["budget_bytes"] = budget.total
    results["budget_parts"] = budget.parts
    table = Table(title=f"ring of {len(rig.names)} cameras, {n} pairs")
    for col in ("what", "ms per set", "pairs/s", "sets (panoramas)/s", "/ floor"):
        table.add_column(col, justify="left" if col == "what" else "right")
    pairs_set = float(np.median(pairs_ms))
    rows: list[tuple[str, float, float | None, float | None]] = [
        ("floor: N x bare OpenCV", floor_set, n * 1e3 / floor_set, 1e3 / floor_set),
        ("pairs one after the other", pairs_set, n * 1e3 / pairs_set, None),
        ("panorama fusion alone", float(np.median(fuse_ms)), None, 1e3 / float(np.median(fuse_ms))),
        ("ours: staged, with the panorama", 1e3 / ours_sets, ours_sets * n, ours_sets),
    ]
    for what, ms, pps, sps in rows:
        table.add_row(
            what,
            f"{ms:.0f}",
            "–" if pps is None else f"{pps:.2f}",
            "–" if sps is None else f"{sps:.2f}",
            f"{ms / floor_set:.2f}",
        )
    console.print(
        f"memory budget of the ring in the service: {budget.total / MIB:.0f} MiB ({budget.largest()}); "
        f"panorama part {budget.parts['panorama'] / MIB:.0f} MiB against the fusion's traced peak "
        f"{fuse_peak / MIB:.0f} MiB; this process's peak RSS {peak_rss / MIB:.0f} MiB"
    )
    return finish("ring_cost", info, results, args.json, table)


if __name__ == "__main__":
    main()
