"""`rig calibrate refine REC --out FILE` on a recording of a ring (more than two cameras; docs/ring.md,
"Refining a ring"): one rotation per camera fitted to every pair's matches at once
(:func:`rig.ring_refine.refine_ring`), measured before and after on the same frame sets (every
pair's vertical disparity, every couple's median disagreement, every pair's coverage) and written
only when nothing got worse.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from rich.table import Table

from cli.console import console, progress_bar
from cli.errors import fail
from rig.recording import Recording

if TYPE_CHECKING:
    from rig.ring_refine import RingRefinement
    from rig.stereo import StereoParams

__all__ = ["RING_FRAMES", "refine_ring_recording"]

#: Frame sets used by default: each costs two consistency studies of every pair.
RING_FRAMES = 3


def _px(value: float | None) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.2f}"


def _tables(result: RingRefinement) -> tuple[Table, Table]:
    pairs = Table(title="each pair: vertical disparity p50 (px) and coverage")
    for col in ("pair", "vertical before → after", "coverage before → after"):
        pairs.add_column(col, justify="left" if col == "pair" else "right")
    for (a, b), before in result.vertical_before.items():
        after = result.vertical_after[(a, b)]
        cov_b, cov_a = result.coverage_before.get((a, b)), result.coverage_after.get((a, b))
        pairs.add_row(
            f"{a}|{b}",
            f"{_px(before.p50_px)} → {_px(after.p50_px)}",
            f"{_px(cov_b)} → {_px(cov_a)}",
        )
    couples = Table(title="couples of pairs sharing a camera: median disagreement")
    for col in ("couple (source → target)", "before", "after"):
        couples.add_column(col, justify="left" if col.startswith("couple") else "right")
    for label, before_share in result.agreement_before.items():
        after_share = result.agreement_after.get(label, math.nan)
        couples.add_row(label, f"{100 * before_share:.2f} %", f"{100 * after_share:.2f} %")
    return pairs, couples


def _frame_sets(rec: Recording, names: list[str], count: int) -> list[dict[str, np.ndarray]]:
    """Up to ``count`` sets spread evenly over ``rec``, each camera's frame in gray."""
    import cv2

    if not len(rec):
        fail(f"{rec.root}: the recording holds no frame set")
    picks = sorted({round(k) for k in np.linspace(0, len(rec) - 1, min(count, len(rec)))})
    records = list(rec)
    return [{n: rec.read_image(records[k], n, cv2.IMREAD_GRAYSCALE) for n in names} for k in picks]


def refine_ring_recording(
    recording: Path, rig_path: Path | None, out: Path, frames: int, stereo: StereoParams | None = None
) -> None:
    """Refine the ring at ``rig_path`` (default: the recording's calibration) from up to
    ``frames`` frame sets of ``recording``, print the figures (the couples' agreement measured
    with ``stereo``, default the defaults), write ``out`` when applied."""
    from cli.pair_options import load_calibration
    from rig.rectification.refine import save_refined
    from rig.ring_refine import RingRefineOptions, refine_ring

    rec = Recording(recording)
    rig, cal_path = load_calibration(rig_path, rec.calibration_path, rings=True)
    missing = [n for n in rig.names if n not in rec.cameras]
    if missing:
        fail(
            f"{recording}: the recording has no camera {', '.join(missing)} of {cal_path} "
            f"(it holds {', '.join(rec.cameras)})"
        )
    sets = _frame_sets(rec, list(rig.names), frames)
    if len(sets) < 2:
        # Fitted and judged on one set, a correction can look right and be an overfit: the real
        # ring's first set alone gave one that made held-out sets worse (docs/ring.md).
        fail(
            f"{recording}: a ring is refined on at least 2 frame sets (got {len(sets)}): one set "
            "cannot tell a correction from an overfit (use --frames 2 or more, or record longer)"
        )
    with progress_bar() as bar:
        task = bar.add_task(f"refining the ring on {len(sets)} set(s) of {recording}", total=None)
        result = refine_ring(
            rig,
            sets,
            rig.pairs,
            options=RingRefineOptions(stereo=stereo),
            progress=lambda done, total: bar.update(task, completed=done, total=total),
        )
    turns = ", ".join(f"{n} {float(np.linalg.norm(r)):.3f}°" for n, r in result.corrections_deg.items())
    console.print(f"cameras turned ({rig.names[0]} holds the rig frame): {turns}", highlight=False)
    for table in _tables(result):
        console.print(table)
    if not result.applied:
        console.print(
            f"{result.reason}; {out} not written, calibration stays {cal_path}",
            highlight=False,
            soft_wrap=True,
        )
        return
    backup = save_refined(result.rig_after, out, cal_path)
    kept = f" (the original is kept as {backup})" if backup is not None else ""
    console.print(f"applied: wrote {out}{kept}; calibration was {cal_path}", highlight=False, soft_wrap=True)
