"""`rig calibrate refine REC --floor-height M` (docs/rectification.md, "Vergence from the
floor"): the right camera's turn about the rectified y (vergence) and z found from a floor
``M`` metres below the rig's origin (:func:`rig.floor_refine.refine_floor`), its figures before
and after printed, and the corrected calibration written only when it was applied.
"""

from __future__ import annotations

from pathlib import Path

from cli.console import console, progress_bar
from rig.floor_refine import recording_frames, refine_floor
from rig.recording import Recording
from rig.rectification.refine import save_refined
from rig.rectified import RectifiedPairConfig

__all__ = ["refine_from_floor"]


def refine_from_floor(
    recording: Path, rig_path: Path | None, out: Path, height_m: float, frames: int
) -> None:
    """Refine the calibration at ``rig_path`` (default: the recording's) from the floor in up to
    ``frames`` pairs of ``recording``, print the figures, write ``out`` when it is applied."""
    from cli.pair_options import load_calibration

    rec = Recording(recording)
    rig, cal_path = load_calibration(rig_path, rec.calibration_path)
    config = RectifiedPairConfig()
    pairs = recording_frames(rec, frames, config)
    with progress_bar() as bar:
        task = bar.add_task(f"the floor in {len(pairs)} pair(s) of {recording}", total=None)
        result = refine_floor(
            rig,
            pairs,
            height_m,
            config=config,
            progress=lambda done, total: bar.update(task, completed=done, total=total),
        )
    for line in result.summary():
        console.print(line, highlight=False, soft_wrap=True)
    if not result.applied:
        console.print(f"{out} not written; calibration stays {cal_path}", highlight=False, soft_wrap=True)
        return
    backup = save_refined(result.rig_after, out, cal_path)
    kept = f" (the original is kept as {backup})" if backup is not None else ""
    console.print(f"wrote {out}{kept}; calibration was {cal_path}", highlight=False, soft_wrap=True)
