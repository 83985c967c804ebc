"""Files of a wide-pair study (:mod:`rig.evaluate.wide_pair`) in its output directory.

``wide_pair.csv`` (one row per variant: size, resolution, coverage, errors, shared rays),
``wide_pair_by_angle.csv`` (per variant and 10° bin of angle off the forward axis),
``wide_pair.png`` (within-3 % fraction and median error against that angle), ``wide_pair.md``
(the tables and the figure) and ``wide_pair.json`` (settings and every number), written last,
atomically: its presence marks a complete run.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import ScalarFormatter

from calibration.atomic import write_atomic
from rig.evaluate.wide_pair import REFERENCE_VARIANT, VariantResult, WideStudy
from rig.sim.lens_effects import lens_for
from rig.sim.presets import get_preset

__all__ = ["WIDE_OUTPUT_FILES", "wide_document", "write_wide_outputs"]

WIDE_OUTPUT_FILES = (
    "wide_pair.json",
    "wide_pair.csv",
    "wide_pair_by_angle.csv",
    "wide_pair.png",
    "wide_pair.md",
)


def _num(x: float | None, digits: int = 5) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), digits)


def _variant_row(study: WideStudy, r: VariantResult) -> dict[str, Any]:
    ref_median, shared_median, shared_sr = r.shared if r.shared else (None, None, None)
    return {
        "variant": r.variant.name,
        "projection": r.projection,
        "width": r.width,
        "height": r.height,
        "pixels": r.pixels,
        "fx_px_per_rad": _num(r.fx, 3),
        "px_per_deg": _num(math.radians(r.fx), 3),
        "valid_sr": _num(r.valid_sr, 4),
        "within_1pct_sr": _num(r.within_sr[0.01], 4),
        "within_3pct_sr": _num(r.within_sr[0.03], 4),
        "within_3pct_of_overlap": _num(r.within_sr[0.03] / study.overlap_sr, 4),
        "median_rel_error": _num(r.median_error),
        "p90_rel_error": _num(r.p90_error),
        "shared_sr": _num(shared_sr, 4),
        "shared_median_rel_error_pinhole": _num(ref_median),
        "shared_median_rel_error": _num(shared_median),
        "process_ms_indicative": _num(r.process_ms, 1),
    }


def wide_document(study: WideStudy) -> dict[str, Any]:
    """Everything of the run as JSON-able data."""
    return {
        "settings": study.config.describe(),
        "overlap_sr": _num(study.overlap_sr, 4),
        "variants": [_variant_row(study, r) for r in study.results],
        "by_angle": {
            r.variant.name: [
                {
                    "angle_deg": [b.lo_deg, b.hi_deg],
                    "overlap_sr": _num(b.overlap_sr, 4),
                    "valid_frac": _num(b.valid_frac, 4),
                    "within_3pct_frac": _num(b.within3_frac, 4),
                    "median_rel_error": _num(b.median_error),
                }
                for b in r.bins
            ]
            for r in study.results
        },
        "timings_s": {k: round(v, 1) for k, v in study.timings_s.items()},
    }


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _plot(study: WideStudy, path: Path) -> None:
    fig = Figure(figsize=(10.0, 4.0), dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    cover, error = fig.subplots(1, 2)
    for r in study.results:
        centres = [(b.lo_deg + b.hi_deg) / 2.0 for b in r.bins]
        style = "-" if r.projection == "latlon" else "--"
        cover.plot(
            centres, [100.0 * b.within3_frac for b in r.bins], style, marker="o", label=r.variant.label
        )
        error.plot(
            centres, [100.0 * b.median_error for b in r.bins], style, marker="o", label=r.variant.label
        )
    cover.set_xlabel("angle off the forward axis (°)")
    cover.set_ylabel("overlap with range within 3 % (%)")
    cover.set_ylim(0, 100)
    error.set_xlabel("angle off the forward axis (°)")
    error.set_ylabel("median |range error| (%)")
    error.set_yscale("log")
    error.yaxis.set_major_formatter(ScalarFormatter())
    cover.legend(fontsize=7, loc="lower left")
    for ax in (cover, error):
        ax.grid(True, alpha=0.3)
    fig.suptitle(
        f"{study.config.preset}: the overlap of the two lenses ({study.overlap_sr:.2f} sr), room scene"
    )
    fig.savefig(path)


def _markdown(study: WideStudy, doc: dict[str, Any]) -> str:
    c = study.config
    poses = ", ".join(map(str, c.poses))
    lines = [
        f"# Wide pair: {c.preset}{' (quick)' if c.quick else ''}",
        "",
        f"The room scene of `rig sim` at {len(c.poses)} pose(s) of its path ({poses} of {c.path_frames}), "
        f"fisheye renders supersampled {c.supersample}×{c.supersample} through the "
        f"{lens_for(c.lens, get_preset(c.preset).scaled(c.scale).lens).describe()}; stereo: the defaults "
        f"with {c.stereo.disparity_range} disparities. The overlap of "
        f"the two lenses: {study.overlap_sr:.3f} sr.",
        "",
        "| variant | pixels | px/deg (centre) | valid sr | within 1 % sr | within 3 % sr (of overlap) "
        "| median error | shared rays: pinhole / this |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row, r in zip(doc["variants"], study.results, strict=True):
        shared = "–"
        if r.variant.name != REFERENCE_VARIANT and row["shared_median_rel_error"] is not None:
            pin, this = row["shared_median_rel_error_pinhole"], row["shared_median_rel_error"]
            shared = f"{100 * pin:.2f} % / {100 * this:.2f} % ({row['shared_sr']:.2f} sr)"
        of_overlap = 100 * r.within_sr[0.03] / study.overlap_sr
        lines.append(
            f"| {r.variant.label} | {r.width}×{r.height} = {r.pixels} | {row['px_per_deg']:.2f} "
            f"| {r.valid_sr:.2f} | {r.within_sr[0.01]:.2f} | {r.within_sr[0.03]:.2f} "
            f"({of_overlap:.0f} %) | {100 * r.median_error:.2f} % | {shared} |"
        )
    lines += ["", "![coverage and error by angle](wide_pair.png)", ""]
    header = "| angle off forward | overlap sr | " + " | ".join(r.variant.name for r in study.results) + " |"
    lines += [
        "Fraction of the overlap with range within 3 % (median error), by angle off the forward axis:",
        "",
        header,
        "|---|---|" + "---|" * len(study.results),
    ]
    for i, b in enumerate(study.results[0].bins):
        cells = []
        for r in study.results:
            rb = r.bins[i]
            cells.append(
                "–"
                if math.isnan(rb.within3_frac)
                else f"{100 * rb.within3_frac:.0f} % ({_pct(rb.median_error)})"
            )
        lines.append(f"| {b.lo_deg:g}–{b.hi_deg:g}° | {b.overlap_sr:.3f} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _pct(x: float) -> str:
    return "–" if math.isnan(x) else f"{100 * x:.2f} %"


def write_wide_outputs(study: WideStudy, out: str | Path) -> Path:
    """Write the study's files into ``out`` (created); returns the path of ``wide_pair.md``."""
    root = Path(out)
    root.mkdir(parents=True, exist_ok=True)
    doc = wide_document(study)
    _write_csv(root / "wide_pair.csv", doc["variants"])
    angle_rows = [
        {"variant": name, "angle_lo_deg": b["angle_deg"][0], "angle_hi_deg": b["angle_deg"][1]}
        | {k: v for k, v in b.items() if k != "angle_deg"}
        for name, bins in doc["by_angle"].items()
        for b in bins
    ]
    _write_csv(root / "wide_pair_by_angle.csv", angle_rows)
    _plot(study, root / "wide_pair.png")
    report = root / "wide_pair.md"
    report.write_text(_markdown(study, doc), encoding="utf-8")
    write_atomic(root / "wide_pair.json", (json.dumps(doc, indent=2, allow_nan=False) + "\n").encode())
    return report
