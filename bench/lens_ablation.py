"""Which of the honest lens's effects costs the matcher its range: the default pipeline on the
room (``rig sim``'s path, middle pose) through the prototype's honest lens, then with one effect
at a time turned off, and through the ideal lens.

Per variant: the share of the overlap's solid angle (the pixels both lenses' tables see) with
valid range, and with range within 3 % of the renderer's exact range (the wide-pair study's
measure, docs/wide-pair.md), on the default lat-lon pair and stereo settings. The renders are
noiseless but for ``--noise`` grey levels of gaussian noise (default: the honest lens's own).

Run: ``.venv/bin/python -m bench.lens_ablation`` (``--quick``: half-size cameras at half the
resolution).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from rich.table import Table

from bench.common import add_common_arguments, console, finish, machine_info, print_machine
from rig.field import pixel_solid_angles
from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPairConfig
from rig.sim import IDEAL_LENS, LensEffects, get_preset, render, room_path, room_scene
from rig.sim.render import render_range
from rig.stereo import StereoParams

__all__ = ["main", "variants"]


def variants(honest: LensEffects) -> dict[str, LensEffects]:
    """The honest lens, it without each effect in turn, and the ideal lens."""
    flat = tuple(replace(e, gain=1.0, gamma=1.0) for e in honest.exposures)
    return {
        "honest": honest,
        "no blur, no defocus": replace(
            honest,
            blur_centre_px=0.0,
            blur_rim_px=0.0,
            exposures=tuple(replace(e, defocus_px=0.0) for e in honest.exposures),
        ),
        "no rim darkening": replace(honest, illumination=()),
        "equal gains": replace(honest, exposures=tuple(replace(e, gain=1.0) for e in honest.exposures)),
        "equal gains and γ": replace(honest, exposures=flat),
        "no rim darkening, equal gains and γ": replace(honest, illumination=(), exposures=flat),
        "no noise": honest.noiseless(),
        "ideal": IDEAL_LENS,
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(
        prog="python -m bench.lens_ablation", description=__doc__.split("\n\n")[0]
    )
    add_common_arguments(parser)
    args = parser.parse_args(argv)
    info = machine_info()
    print_machine(info, "the honest lens's effects, one at a time, against the matcher's range")
    scale = 0.5 if args.quick else 1.0
    preset = get_preset("prototype").scaled(scale)
    vpc = RectifiedPairConfig(projection="latlon", px_per_deg=2.8) if args.quick else RectifiedPairConfig()
    stereo = StereoParams(disparity_range=64) if args.quick else StereoParams()
    scene, T = room_scene(0), room_path(2, 5)
    rows: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory(prefix="lens-ablation-") as tmp:
        pipe = DepthPipeline(preset.rig, vpc, stereo, cache_dir=Path(tmp), tune_malloc=False)
        pair = pipe.pair
        truth, _ = render_range(scene, pair.camera, T @ pair.T_rig_rect[pair.left])
        solid = pixel_solid_angles(pair.camera)
        both = pipe.luts["left"].valid & pipe.luts["right"].valid
        for name, lens in variants(preset.lens).items():
            t0 = time.perf_counter()
            images = [
                render(
                    scene,
                    preset.rig.cameras[cam],
                    T @ preset.rig.T_rig_cam[cam],
                    seed=k,
                    lens=lens,
                    camera_index=k,
                ).image
                for k, cam in enumerate(("left", "right"))
            ]
            frame = pipe.process(images[0], images[1])
            with np.errstate(invalid="ignore", divide="ignore"):
                good = frame.valid & (np.abs(frame.range / truth - 1.0) < 0.03)
            rows[name] = {
                "valid": float(solid[frame.valid & both].sum() / solid[both].sum()),
                "within_3pct": float(solid[good & both].sum() / solid[both].sum()),
            }
            console.print(f"{name}: {time.perf_counter() - t0:.0f} s")
    table = Table(
        title=f"share of the overlap, default lat-lon pair ({pair.camera.width}×{pair.camera.height})"
    )
    for col in ("lens", "valid range", "within 3 %"):
        table.add_column(col, justify="left" if col == "lens" else "right")
    for name, r in rows.items():
        table.add_row(name, f"{100 * r['valid']:.1f} %", f"{100 * r['within_3pct']:.1f} %")
    return finish("lens_ablation", info, {"scale": scale, "variants": rows}, args.json, table)


if __name__ == "__main__":
    main()
