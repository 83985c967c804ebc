"""The vergence from the floor (docs/rectification.md, "Vergence from the floor"): the figures
of :func:`rig.floor_refine.refine_floor`.

1. Renders: the half-size prototype recorded in the demo room (floor 1.2 m below the rig, two
   frames, its honest lens: ``rig sim``'s default) with the right camera turned about y by
   +0.3°, -0.3° and not at all, refined from the nominal calibration at the true height; the
   correct rig also told heights 5 and 10 cm off. Turn found against the truth, the floor's
   residual and range error before and after, whether the gate applied it.
2. ``--real``: every adjacent pair of ../shared/data/ring_sweepnet_indoor (three frames) at a
   few plausible heights (the dataset gives none; the range puts the floor ≈0.68 m down).

Run: ``.venv/bin/python -m bench.floor_refine [--real]``. Not a speed benchmark: it prints
accuracy figures.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from bench.common import console
from rig.errors import RectificationError
from rig.floor_refine import FloorRefinement, recording_frames, refine_floor
from rig.recording import Recording
from rig.rectified import RectifiedPairConfig
from rig.ring import adjacent_pairs
from tests.helpers.ring import RING_DIR, load_ring
from tests.rig.rectification_renders import nominal_rig, perturbed, render_room

HEIGHT_M = 1.2  # the room's floor below the rig (rig.sim.scene)
REAL_HEIGHTS_M = (0.65, 0.68, 0.70)


def _print(label: str, result: FloorRefinement) -> None:
    console.print(
        f"[bold]{label}[/bold]\n  " + "\n  ".join(result.summary()), highlight=False, soft_wrap=True
    )


def renders(work: Path) -> None:
    console.print("[bold]1. Renders: prototype (half size, honest lens) in the room, floor 1.2 m down[/bold]")
    for vergence in (0.3, -0.3, 0.0):
        rec = render_room(
            work / f"turn{vergence:+.1f}", frames=2, truth=perturbed(nominal_rig(), (0.0, vergence, 0.0))
        )
        frames = recording_frames(Recording(rec), 2)
        heights = (HEIGHT_M,) if vergence else (HEIGHT_M, HEIGHT_M + 0.05, HEIGHT_M + 0.1)
        for height in heights:
            r = refine_floor(nominal_rig(), frames, height)
            found = r.correction_deg
            _print(
                f"truth: {vergence:+.2f}° about y, 0 about z; told {height:.2f} m -> found {found[0]:+.4f}°, "
                f"{found[1]:+.4f}° (error {found[0] - vergence:+.4f}°, {found[1]:+.4f}°)",
                r,
            )


def real(root: Path) -> None:
    console.print(
        f"[bold]2. The real ring ({root}), three frames, heights unknown: tried {REAL_HEIGHTS_M} m[/bold]"
    )
    ring = load_ring(root)
    for left, right in adjacent_pairs(ring.rig):
        frames = [(f[left], f[right]) for f in ring.frames]
        config = RectifiedPairConfig(left=left, right=right)
        for height in REAL_HEIGHTS_M:
            try:
                _print(
                    f"{left}|{right}, told {height:.2f} m",
                    refine_floor(ring.rig, frames, height, config=config),
                )
            except RectificationError as err:
                console.print(
                    f"[bold]{left}|{right}, told {height:.2f} m[/bold]\n  {err}",
                    highlight=False,
                    soft_wrap=True,
                )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--real", action="store_true", help="also the real ring at plausible heights")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as work:
        renders(Path(work))
    if args.real:
        shared = Path(
            os.environ.get("RIG_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")
        )
        real(shared / RING_DIR)


if __name__ == "__main__":
    main()
