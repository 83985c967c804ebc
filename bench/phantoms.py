"""Phantom obstacles per stereo setting: the figures the stereo defaults are chosen by.

Scenes: :data:`rig.evaluate.phantoms.SCENES` (the README's walkthrough room, a brick wall, a
wall of bars, a low-texture wall, and a wall 0.3 m ahead) rendered once through the
``prototype`` rig (its honest lens; ``--lens ideal`` for none) at the default 640×480 / 90° VPC
and kept in the bench cache. For each
candidate setting every scene goes through :class:`rig.pipeline.DepthPipeline`, and the table
gives per scene the *phantom rate* (valid pixels nearer than half the truth, per valid pixel) and
the *valid fraction* (valid pixels per pixel with a surface), then over all scenes: phantoms,
the worst scene, the valid fraction, the *lost rate* of the near wall (valid pixels further than
twice the truth: a real obstacle placed too far) and the CPU per frame (process time, every
thread, median over the scenes and ``--repeat`` runs) at 640×480 and 1280×960, against a bare
``cv2.StereoSGBM`` of the old default (128 disparities) on the same VPC pair.

A *confidence floor* candidate serves only pixels whose confidence reaches the floor (a mask
applied here: the pipeline has no such option).

Run: ``flock /tmp/rig-bench.lock .venv/bin/python -m bench.phantoms`` (``--quick``: two scenes at
320×240, seconds; ``--room-frames N`` adds N frames of the walk through the room).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rich.table import Table

from bench.common import (
    add_common_arguments,
    bench_cache_dir,
    console,
    finish,
    machine_info,
    median,
    print_machine,
)
from rig.evaluate.phantoms import (
    PHANTOM_VPC,
    SCENES,
    PhantomScene,
    PhantomStats,
    phantom_stats,
    render_phantom_shot,
    room_walk,
)
from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPairConfig
from rig.sim import get_preset
from rig.sim.lens_effects import LENS_CHOICES
from rig.stereo import StereoParams, create_opencv_matcher

__all__ = ["CANDIDATES", "Candidate", "main"]

RENDER_VERSION = 1
SUPERSAMPLE = 2
NEAR_SCENE = "near-wall"


@dataclass(frozen=True)
class Candidate:
    label: str
    stereo: dict[str, Any] = field(default_factory=dict)  # over StereoParams()
    confidence_floor: float | None = None

    @property
    def params(self) -> StereoParams:
        return StereoParams(**self.stereo)


# The settings chosen against phantoms were measured with the exact search (OpenCV's matcher over
# the whole range, the left-right check's second run too); the defaults since (the exact search,
# that second run at half resolution) and the coarse-to-fine option with the chosen ones, and with
# 256 disparities.
EXACT = {"coarse_to_fine": False, "lr_check_scale": 1}
C2F = {"coarse_to_fine": True}
OLD = {"disparity_range": 128, "lr_check": False, **EXACT}
CANDIDATES = (
    Candidate("128 (before)", OLD),
    Candidate("128, uniqueness 20", {**OLD, "uniqueness_ratio": 20}),
    Candidate("128, confidence ≥ 0.5", OLD, 0.5),
    Candidate("128 + LR check", {"disparity_range": 128, "lr_check": True, **EXACT}),
    Candidate("96", {"disparity_range": 96, "lr_check": False, **EXACT}),
    Candidate("96 + LR check (exact)", EXACT),
    Candidate("64 + LR check", {"disparity_range": 64, "lr_check": True, **EXACT}),
    Candidate("96 + LR check at half resolution (default)", {}),
    Candidate("96 + LR check, coarse-to-fine", C2F),
    Candidate("64 + LR check, coarse-to-fine", {"disparity_range": 64, **C2F}),
    Candidate("256 + LR check, coarse-to-fine", {"disparity_range": 256, **C2F}),
)
QUICK = (CANDIDATES[0], CANDIDATES[7])


@dataclass(frozen=True)
class Shot:
    name: str
    left: np.ndarray[Any, Any]
    right: np.ndarray[Any, Any]
    truth: np.ndarray[Any, Any]


def cached_shot(scene: PhantomScene, vpc: RectifiedPairConfig, lens: str = "honest") -> Shot:
    """The scene's render through ``lens``, from the bench cache or rendered (and kept) now."""
    folder = bench_cache_dir() / "phantoms"
    path = folder / f"{scene.name}-v{RENDER_VERSION}-{lens}-{vpc.width}x{vpc.height}-ss{SUPERSAMPLE}.npz"
    if path.is_file():
        with np.load(path) as z:
            return Shot(scene.name, z["left"], z["right"], z["truth"])
    t0 = time.perf_counter()
    s = render_phantom_shot(scene, vpc=vpc, supersample=SUPERSAMPLE, lens=lens)
    console.print(f"rendered {scene.name} ({scene.what}) in {time.perf_counter() - t0:.0f} s")
    folder.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, left=s.left, right=s.right, truth=s.truth)
    tmp.replace(path)
    return Shot(scene.name, s.left, s.right, s.truth)


def _stats(pipe: DepthPipeline, cand: Candidate, shot: Shot) -> PhantomStats:
    frame = pipe.process(shot.left, shot.right)
    valid = frame.valid
    if cand.confidence_floor is not None and frame.confidence is not None:
        valid = valid & (frame.confidence >= cand.confidence_floor)
    return phantom_stats(frame.depth, valid, shot.truth)


def _cpu_ms(pipe: DepthPipeline, shots: list[Shot], repeat: int) -> float:
    """Median process CPU time (ms, every thread) of one ``pipe.process`` over the shots."""
    times = []
    pipe.process(shots[0].left, shots[0].right)  # warm-up
    for _ in range(repeat):
        for s in shots:
            c0 = time.process_time()
            pipe.process(s.left, s.right)
            times.append((time.process_time() - c0) * 1e3)
    return median(times)


def _bare_cpu_ms(pipe: DepthPipeline, shots: list[Shot], repeat: int) -> float:
    """The same for the bare OpenCV matcher of the old default on the VPC pairs."""
    sgbm = create_opencv_matcher(StereoParams(**OLD))
    pairs = [pipe.remap(s.left, s.right) for s in shots]
    times = []
    for _ in range(repeat):
        for left, right in pairs:
            c0 = time.process_time()
            sgbm.compute(left, right)
            times.append((time.process_time() - c0) * 1e3)
    return median(times)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m bench.phantoms", description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    parser.add_argument("--room-frames", type=int, default=0, help="also N frames of a walk through the room")
    parser.add_argument("--lens", choices=LENS_CHOICES, default="honest", help="the renders' lens effects")
    args = parser.parse_args(argv)
    info = machine_info()
    print_machine(
        info,
        f"phantom obstacles per stereo setting, {args.lens} lens (shared machine: CPU figures are noisy)",
    )
    quick = args.quick
    vpc = RectifiedPairConfig(width=320, height=240) if quick else PHANTOM_VPC
    scenes = [SCENES["stripes"], SCENES["low-texture"]] if quick else list(SCENES.values())
    scenes += [room_walk(i, args.room_frames) for i in range(args.room_frames)]
    candidates = QUICK if quick else CANDIDATES
    repeat = args.repeat or (1 if quick else 3)
    shots = [cached_shot(s, vpc, args.lens) for s in scenes]
    rig = get_preset("prototype").rig
    tmp = bench_cache_dir() / "phantoms" / "lut"
    pipe = DepthPipeline(rig, vpc, cache_dir=tmp)
    big = None if quick else DepthPipeline(rig, RectifiedPairConfig(width=1280, height=960), cache_dir=tmp)
    bare = {"small": _bare_cpu_ms(pipe, shots, repeat)}
    if big is not None:
        bare["big"] = _bare_cpu_ms(big, shots[:2], repeat)

    per_scene = Table(title=f"phantom rate % / valid % per scene (VPC {vpc.width}×{vpc.height})")
    per_scene.add_column("setting")
    for s in shots:
        per_scene.add_column(s.name, justify="right")
    summary = Table(title="over all scenes")
    for col in (
        "setting",
        "phantoms %",
        "worst scene %",
        "valid %",
        f"{NEAR_SCENE} lost %",
        f"CPU ms/frame {vpc.width}×{vpc.height} (× bare SGBM 128)",
        "CPU ms/frame 1280×960 (× bare)",
    ):
        summary.add_column(col, justify="right")
    rows = []
    for cand in candidates:
        pipe.apply(stereo=cand.params)
        stats = {s.name: _stats(pipe, cand, s) for s in shots}
        total = sum(stats.values(), PhantomStats(0, 0, 0, 0))
        worst = max(st.phantom_rate for st in stats.values())
        cpu = _cpu_ms(pipe, shots, repeat)
        cpu_big = None
        if big is not None:
            big.apply(stereo=cand.params)
            cpu_big = _cpu_ms(big, shots[:2], repeat)
        near = stats.get(NEAR_SCENE)
        rows.append(
            {
                "setting": cand.label,
                "stereo": cand.params.model_dump(),
                "confidence_floor": cand.confidence_floor,
                "scenes": {n: st.__dict__ for n, st in stats.items()},
                "phantom_rate": total.phantom_rate,
                "worst_phantom_rate": worst,
                "valid_fraction": total.valid_fraction,
                "near_lost_rate": None if near is None else near.lost_rate,
                "cpu_ms": cpu,
                "cpu_ms_1280x960": cpu_big,
            }
        )
        per_scene.add_row(
            cand.label,
            *(f"{100 * st.phantom_rate:.3f} / {100 * st.valid_fraction:.1f}" for st in stats.values()),
        )
        summary.add_row(
            cand.label,
            f"{100 * total.phantom_rate:.3f}",
            f"{100 * worst:.3f}",
            f"{100 * total.valid_fraction:.1f}",
            "–" if near is None else f"{100 * near.lost_rate:.1f}",
            f"{cpu:.0f} ({cpu / bare['small']:.2f})",
            "–" if cpu_big is None else f"{cpu_big:.0f} ({cpu_big / bare['big']:.2f})",
        )
    console.print(per_scene)
    console.print(
        f"bare cv2.StereoSGBM, 128 disparities, SGBM_3WAY: {bare['small']:.0f} ms CPU per pair at "
        f"{vpc.width}×{vpc.height}" + (f", {bare['big']:.0f} ms at 1280×960" if "big" in bare else "")
    )
    return finish(
        "phantoms",
        info,
        {
            "vpc": [vpc.width, vpc.height],
            "supersample": SUPERSAMPLE,
            "repeat": repeat,
            "bare_sgbm_cpu_ms": bare,
            "rows": rows,
        },
        args.json,
        summary,
    )


if __name__ == "__main__":
    main()
