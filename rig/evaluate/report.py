"""Files of an evaluation run in its output directory.

``results.json`` (keys: preset, calibration, image_difference, depth, matchers, and extrinsics,
the chain of docs/rectification.md; NaN written as null), ``run.json`` (settings, σd of the
theory, fits, failures, timings, the git commit of the code, versions), the tables as CSV, the
figures as PNG, ``difference/`` (the VPC images and contrast-enhanced difference images) and
``report.md`` (tables, figures, agreement with the paper). ``results.json`` is written last,
atomically: its presence marks a complete run.
"""

from __future__ import annotations

import csv
import json
import math
import os
import platform
from dataclasses import asdict
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from calibration.atomic import write_atomic
from rig.errors import EvaluationError
from rig.evaluate.agreement import check_claims, mean_ratio
from rig.evaluate.depth_quality import REFERENCE, THEORY, CurvePoint
from rig.evaluate.extrinsics import CALIBRATED, REFINED, PoseError
from rig.evaluate.markdown import render_markdown
from rig.evaluate.matchers import MATCHER_LABELS
from rig.evaluate.plots import coverage_plot, depth_plot, depth_ratio_plot, difference_montage, matcher_plot
from rig.evaluate.runner import EvaluationRun
from rig.sim.lens_effects import lens_for

__all__ = ["DIFFERENCE_GAIN", "OUTPUT_FILES", "results_document", "write_outputs"]

#: Contrast gain of the saved difference images (the paper's Fig. 6 "increased the contrast").
DIFFERENCE_GAIN = 8.0
OUTPUT_FILES = (
    "results.json",
    "run.json",
    "report.md",
    "calibration.csv",
    "image_difference.csv",
    "depth.csv",
    "depth_fit.csv",
    "matchers.csv",
    "depth_rms.png",
    "depth_ratio.png",
    "matchers.png",
    "image_difference.png",
    "calibration_coverage.png",
)


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _clean(obj: Any) -> Any:
    """JSON-safe: NaN/inf -> None, tuples -> lists, numpy scalars -> Python."""
    if isinstance(obj, dict):
        return _clean_document(obj)
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.generic):
        return _clean(obj.item())
    if isinstance(obj, float):
        return _num(obj)
    return obj


def _clean_document(doc: dict[Any, Any]) -> dict[str, Any]:
    """A JSON-safe copy of ``doc`` (see :func:`_clean`), keys as strings."""
    return {str(k): _clean(v) for k, v in doc.items()}


def _params(params: dict[str, Any]) -> dict[str, Any]:
    """Calibrated parameters as stored in rig.yaml, without Scaramuzza's derived inverse
    polynomial (it is recomputed from ``poly`` on load)."""
    return {k: v for k, v in params.items() if k != "invpol"}


def _calibration(run: EvaluationRun) -> dict[str, Any]:
    study = run.calibration
    left = run.pair.left
    out: dict[str, Any] = {}
    for model, mc in study.models.items():
        entry: dict[str, Any] = {"rms_px": None, "params": None, "converged": mc.converged, "error": mc.error}
        if mc.ok:
            per = {}
            for cam, lens in study.lens_of.items():
                r = mc.results[lens]
                per[cam] = {
                    "rms_px": r.rms,
                    # The fit on the detector's corners, before the corner refinement.
                    "rms_detector_px": r.refinement.rms_before if r.refinement is not None else r.rms,
                    "corner_rms_px": mc.corner_rms_px.get(lens),
                    "params": _params(r.camera.to_dict()["params"]),
                    "n_views": len(r.views),
                    "n_corners": r.n_corners,
                    "max_angle_deg": r.max_angle_deg,
                    "converged": r.converged,
                }
            entry |= {"rms_px": per[left]["rms_px"], "params": per[left]["params"], "per_camera": per}
        out[model] = entry
    return out


def _point(p: CurvePoint, theory: bool = False) -> dict[str, Any]:
    d: dict[str, Any] = {
        "k": p.k,
        "rms_m": p.rms_m,
        "std_m": p.std_m,
        "mean_m": p.mean_m,
        "valid_frac": None if theory else p.valid_frac,
    }
    d["fit_rms_m"] = p.fit_rms_m
    d["sigma_d_px" if theory else "disparity_rms_px"] = p.disparity_rms_px
    if not theory:
        d["n_textures"] = p.n
    return d


def _pose(e: PoseError | None) -> dict[str, float] | None:
    if e is None:
        return None
    return {"rotation_deg": e.rotation_deg, "translation_mm": e.translation_mm, "baseline_mm": e.baseline_mm}


def _extrinsics(run: EvaluationRun) -> dict[str, Any] | None:
    """The extrinsics chain: pose errors against the truth and the depth error ratio to the
    Reference with the true, calibrated and refined extrinsics."""
    ex = run.extrinsics
    if ex is None:
        return None
    ref = run.depth.get(REFERENCE, [])
    curves = {"true": ex.model, "calibrated": CALIBRATED, "refined": REFINED}
    ratio = {k: mean_ratio(run.depth[c], ref) if c in run.depth else None for k, c in curves.items()}
    out: dict[str, Any] = {
        "model": ex.model,
        "board_views": ex.board_views,
        "common_views": ex.common_views,
        "stereo_rms_px": ex.stereo_rms_px,
        "calibrated": _pose(ex.calibrated),
        "calibrated_rotation_sigma_deg": ex.calibrated_sigma_deg,
        "refined": _pose(ex.refined),
        "depth_rms_over_reference": ratio,
        "error": ex.error,
    }
    r = ex.refinement
    if r is not None:
        out["refinement"] = {
            "correction_deg": r.fit.angle_deg,
            "correction_sigma_deg": r.fit.angle_sigma_deg,
            "baseline_direction": r.fit.direction_note,
            "matches": r.matches,
            "inliers": r.fit.n_inliers,
            "frames": len(r.matches_per_frame),
            "vertical_disparity_p50_px": [r.before.p50_px, r.after.p50_px],
            "vertical_disparity_p95_px": [r.before.p95_px, r.after.p95_px],
        }
    return out


def results_document(run: EvaluationRun) -> dict[str, Any]:
    """The content of results.json (with ``extrinsics``, the chain of docs/rectification.md)."""
    depth = {name: [_point(p, name == THEORY) for p in pts] for name, pts in run.depth.items()}
    matchers = {
        name: {
            "label": MATCHER_LABELS.get(name, name),
            "time_ms": ms,
            "per_distance": [
                {
                    "k": p.k,
                    "rms_px": p.rms_px,
                    "rms_inlier_px": p.rms_inlier_px,
                    "bad1_frac": p.bad1_frac,
                    "valid_frac": p.valid_frac,
                }
                for p in points
            ],
        }
        for name, (points, ms) in run.matchers.items()
    }
    doc = {
        "preset": run.config.preset,
        "calibration": _calibration(run),
        "image_difference": {n: r.mad_whole for n, r in run.distortion.results.items()},
        "depth": depth,
        "matchers": matchers,
        "extrinsics": _extrinsics(run),
    }
    return _clean_document(doc)


def _run_document(run: EvaluationRun) -> dict[str, Any]:
    cal = run.calibration
    return _clean_document(
        {
            "settings": run.config.describe(),
            "preset_description": run.preset.description,
            "vpc": run.pair.as_json(),
            "lens_effects": asdict(lens_for(run.config.lens, run.preset.lens)),
            "theory_sigma_d_px": run.theory_sigma_d_px,
            "depth_fits": {n: list(f) if f else None for n, f in run.depth_fits.items()},
            "failures": {
                "calibration": {m: mc.error for m, mc in cal.models.items() if mc.error},
                "depth": run.depth_errors,
                "image_difference": {n: r.error for n, r in run.distortion.results.items() if r.error},
            },
            "calibration_views": {
                lens: {
                    "rendered": len(v.poses),
                    "detected": v.n_detected,
                    "detector_rms_px": v.detector_rms_px,
                    "max_angle_deg": v.max_angle_deg,
                }
                for lens, v in cal.views.items()
            },
            "timings_s": run.timings_s,
            "source": run.source.as_json() if run.source else None,
            "versions": {
                "python": platform.python_version(),
                "numpy": np.__version__,
                "opencv": cv2.__version__,
            },
            "machine": {"cpu_count": os.cpu_count()},
        }
    )


def _write_csv(path: Path, header: list[str], rows: list[list[Any]]) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for row in rows:
            w.writerow(["" if v is None else (f"{v:.6g}" if isinstance(v, float) else v) for v in row])


def _write_tables(run: EvaluationRun, doc: dict[str, Any], out: Path) -> None:
    rows: list[list[Any]] = []
    keys = ["rms_px", "rms_detector_px", "corner_rms_px", "n_views", "max_angle_deg", "converged"]
    for model, e in doc["calibration"].items():
        for cam, c in (e.get("per_camera") or {"-": None}).items():
            if c is None:
                rows.append([model, "-", *[None] * (len(keys) - 1), False, e["error"], ""])
                continue
            params = "; ".join(f"{k}={v}" for k, v in c["params"].items())
            rows.append([model, cam, *(c[k] for k in keys), e["error"] or "", params])
    _write_csv(out / "calibration.csv", ["model", "camera", *keys, "error", "params"], rows)
    _write_csv(
        out / "image_difference.csv",
        ["model", "mad_whole", "mad_central", "valid_frac", "error"],
        [
            [n, _num(r.mad_whole), _num(r.mad_central), r.valid_frac, r.error or ""]
            for n, r in run.distortion.results.items()
        ],
    )
    _write_csv(
        out / "depth.csv",
        ["curve", "k", "distance_m", "rms_m", "std_m", "mean_m", "valid_frac", "fit_rms_m",
         "disparity_rms_px"],
        [
            [n, p.k, p.k * run.pair.baseline_m, *map(_num, (p.rms_m, p.std_m, p.mean_m, p.valid_frac)),
             p.fit_rms_m, _num(p.disparity_rms_px)]
            for n, pts in run.depth.items()
            for p in pts
        ],
    )  # fmt: skip
    _write_csv(
        out / "depth_fit.csv",
        ["curve", "a2", "a1", "a0"],
        [[n, *f] for n, f in run.depth_fits.items() if f is not None],
    )
    _write_csv(
        out / "matchers.csv",
        ["matcher", "k", "rms_px", "rms_inlier_px", "bad1_frac", "valid_frac", "time_ms"],
        [[n, p.k, _num(p.rms_px), _num(p.rms_inlier_px), _num(p.bad1_frac), p.valid_frac, ms]
         for n, (pts, ms) in run.matchers.items() for p in pts],
    )  # fmt: skip


def _write_png(path: Path, image: np.ndarray) -> None:
    if not cv2.imwrite(str(path), image):
        raise EvaluationError(f"{path}: cannot write the image")


def _write_figures(run: EvaluationRun, out: Path) -> None:
    preset = run.config.preset
    n_tex = len(run.config.textures)
    depth_plot(out / "depth_rms.png", run.depth, run.depth_fits,
               f"{preset}: depth error of the plane (mean of {n_tex} textures)")  # fmt: skip
    depth_ratio_plot(
        out / "depth_ratio.png", run.depth, f"{preset}: RMS depth error relative to the Reference"
    )
    matcher_plot(out / "matchers.png", run.matchers, f"{preset}: matchers on the Reference pairs")
    diff_dir = out / "difference"
    diff_dir.mkdir(exist_ok=True)
    _write_png(diff_dir / "reference.png", run.distortion.reference)
    shown = {}
    for name, r in run.distortion.results.items():
        if r.rect_image is None or r.diff_image is None:
            continue
        _write_png(diff_dir / f"{name}_vpc.png", r.rect_image)
        enhanced = np.clip(r.diff_image.astype(np.float32) * DIFFERENCE_GAIN, 0, 255).astype(np.uint8)
        _write_png(diff_dir / f"{name}_diff.png", enhanced)
        shown[name] = (r.diff_image, r.mad_whole)
    difference_montage(
        out / "image_difference.png", run.distortion.reference, shown, DIFFERENCE_GAIN,
        f"{preset}: |VPC image − Reference| ×{DIFFERENCE_GAIN:g} (mean absolute difference, grey levels)",
    )  # fmt: skip
    lens_name = run.calibration.lens_of[run.pair.left]
    views = run.calibration.views[lens_name]
    p = views.lens.param_dict
    coverage_plot(
        out / "calibration_coverage.png", views.lens.width, views.lens.height,
        [c for c in views.corners if c is not None], (float(p["cx"]), float(p["cy"])),
        f"{preset} {lens_name} lens: {views.n_detected} of {len(views.poses)} boards detected, "
        f"corners up to {views.max_angle_deg:.1f}° off axis",
    )  # fmt: skip


def write_outputs(run: EvaluationRun, out: str | Path) -> Path:
    """Write every output file into ``out`` (created if needed); returns the report's path."""
    root = Path(out)
    try:
        root.mkdir(parents=True, exist_ok=True)
        doc = results_document(run)
        _write_tables(run, doc, root)
        _write_figures(run, root)
        (root / "run.json").write_text(json.dumps(_run_document(run), indent=2, allow_nan=False) + "\n")
        claims = check_claims(
            {m: e["rms_px"] for m, e in doc["calibration"].items() if e["rms_px"] is not None},
            {n: v for n, v in doc["image_difference"].items() if v is not None},
            {n: c for n, c in run.depth.items() if n != THEORY},
        )
        report = root / "report.md"
        report.write_text(render_markdown(run, doc, claims))
        write_atomic(root / "results.json", (json.dumps(doc, indent=2, allow_nan=False) + "\n").encode())
    except OSError as err:
        raise EvaluationError(f"{root}: cannot write the evaluation output ({err.strerror or err})") from err
    return report
