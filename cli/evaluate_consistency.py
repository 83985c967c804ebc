"""`rig evaluate --study consistency REC --calibration RIG`: the cross-pair consistency of a rig
of N cameras on a recording's frame sets, without ground truth (docs/ring.md): for every couple
of stereo pairs sharing a camera, the share of points both range, the median |relative
disagreement|, its signed median (a bias) and the shares within 3 % and 10 %; the coverage of each
pair. The work is :func:`rig.evaluate.consistency_study.consistency_study`'s."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import TYPE_CHECKING

from rich.table import Table

from cli.console import console, progress_bar
from cli.errors import fail
from cli.pair_options import load_calibration
from cli.pipeline_options import load_stereo_params

if TYPE_CHECKING:
    from rig.evaluate.consistency_study import ConsistencyStudy

__all__ = ["consistency_command"]


def _pct(x: float, signed: bool = False) -> str:
    return "–" if not math.isfinite(x) else (f"{100 * x:+.2f} %" if signed else f"{100 * x:.2f} %")


def _share(x: float) -> str:
    return "–" if not math.isfinite(x) else f"{x:.3f}"


def _tables(study: ConsistencyStudy, title: str) -> tuple[Table, Table]:
    couples = Table(title=f"consistency {title}: {study.frames} sets")
    columns = (
        "couple",
        "points",
        "both range",
        "median |e|",
        "signed",
        "within 3 %",
        "within 10 %",
        "median |dd|",
    )
    for col in columns:
        couples.add_column(col, justify="left" if col == "couple" else "right")
    for c in study.couples:
        f = c.figures
        couples.add_row(
            c.couple.label,
            str(f.points),
            _share(f.both_share),
            _pct(f.median_abs),
            _pct(f.median_signed, signed=True),
            _share(f.within_3),
            _share(f.within_10),
            "–" if not math.isfinite(f.median_abs_px) else f"{f.median_abs_px:.2f} px",
        )
    coverage = Table(title="coverage per pair (share of its view's solid angle with range)")
    for col in ("pair", "mean", "per set"):
        coverage.add_column(col, justify="left" if col == "pair" else "right")
    for p in study.pairs:
        coverage.add_row(p.label, _share(p.mean_coverage), ", ".join(_share(c) for c in p.coverage))
    return couples, coverage


def consistency_command(
    recording: Path | None,
    calibration: Path | None,
    stereo: Path | None,
    cache_dir: Path | None,
    json_path: Path | None,
) -> None:
    """The study of ``recording`` (a recording directory of N cameras) with ``calibration``
    (default: its calibration.yaml); prints the tables, and writes them as JSON to ``json_path``."""
    from calibration.atomic import write_atomic
    from rig.capture.recorded import open_recording
    from rig.evaluate.consistency_study import consistency_study
    from rig.rig_depth import RecordingFrames
    from rig.ring import stereo_pairs

    if recording is None:
        fail("--study consistency needs a recording: rig evaluate --study consistency REC --calibration RIG")
    rec = open_recording(recording)
    rig, cal_path = load_calibration(calibration, rec.calibration_path, rings=True)
    pairs = stereo_pairs(rig)
    if len(pairs) < 2:
        named = ", ".join("|".join(p) for p in pairs)
        fail(f"{cal_path}: the rig's stereo pairs ({named}) share no camera: no couple to compare")
    if not rec.pairs:
        fail(f"{rec.root}: the recording holds no frame set")
    cameras = [n for n in rig.names if any(n in p for p in pairs)]
    frames = RecordingFrames(rec, rig, cameras)
    params = load_stereo_params(stereo) if stereo is not None else None
    logging.getLogger("rig.pipeline").setLevel(logging.ERROR)  # the pairs' field notes
    with progress_bar() as bar:
        task = bar.add_task("consistency", total=len(frames) * len(pairs))
        study = consistency_study(
            rig,
            frames,
            pairs,
            stereo=params,
            cache_dir=cache_dir,
            progress=lambda done, total: bar.update(task, completed=done, total=total),
        )
    for table in _tables(study, f"{rec.root.name} ({cal_path.name})"):
        console.print(table)
    if json_path is not None:
        doc = {"recording": str(rec.root), "calibration": str(cal_path), **study.as_dict()}
        try:
            write_atomic(json_path, json.dumps(_finite(doc), indent=2, allow_nan=False).encode() + b"\n")
        except OSError as err:
            fail(f"--json {json_path}: cannot write ({err.strerror or err})")
        console.print(f"wrote {json_path}", highlight=False)


def _finite(value: object) -> object:
    """``value`` with every NaN or infinite number as None (JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
