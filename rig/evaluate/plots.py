"""Figures of ``rig evaluate`` (matplotlib, Agg canvas, no global pyplot state).

``depth_plot``: the paper's Fig. 7 layout — x the plane's distance in baselines, y the RMS depth
error, error bars one standard deviation, markers the measurements, lines their 2nd-order
polynomial fits, the theoretical curve dashed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from numpy.typing import NDArray

from rig.evaluate.depth_quality import REFERENCE, THEORY, TRUE_LENS, CurvePoint
from rig.evaluate.extrinsics import CALIBRATED, REFINED
from rig.evaluate.matchers import MATCHER_LABELS, MatcherPoint

__all__ = [
    "CURVE_LABELS",
    "coverage_plot",
    "depth_plot",
    "depth_ratio_plot",
    "difference_montage",
    "matcher_plot",
]

CURVE_LABELS: dict[str, str] = {
    REFERENCE: "Reference (pinholes at the VPC poses)",
    TRUE_LENS: "true lens (exact model)",
    THEORY: "theory Z²·σd/(fx·B)",
    "kannala_brandt": "Kannala-Brandt",
    "mei": "Mei",
    "scaramuzza": "Scaramuzza",
    "equidistant": "equidistant (atan)",
    "double_sphere": "double sphere",
    "eucm": "EUCM",
    CALIBRATED: "calibrated extrinsics (lenses of the extrinsics model)",
    REFINED: "refined extrinsics (lenses of the extrinsics model)",
}
_STYLE: dict[str, dict[str, object]] = {
    REFERENCE: {"color": "black", "marker": "s"},
    TRUE_LENS: {"color": "0.55", "marker": "D"},
    "kannala_brandt": {"color": "tab:blue", "marker": "o"},
    "mei": {"color": "tab:orange", "marker": "^"},
    "scaramuzza": {"color": "tab:red", "marker": "v"},
    "equidistant": {"color": "tab:green", "marker": "<"},
    "double_sphere": {"color": "tab:purple", "marker": ">"},
    "eucm": {"color": "tab:brown", "marker": "P"},
    CALIBRATED: {"color": "tab:cyan", "marker": "x"},
    REFINED: {"color": "tab:olive", "marker": "+"},
}


def label(name: str) -> str:
    return CURVE_LABELS.get(name, name)


def _figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    return path


def _finite(points: Sequence[CurvePoint]) -> list[CurvePoint]:
    return [p for p in points if math.isfinite(p.rms_m)]


def depth_plot(
    path: Path,
    curves: Mapping[str, Sequence[CurvePoint]],
    fits: Mapping[str, tuple[float, float, float] | None],
    title: str,
) -> Path:
    """The paper's depth-quality figure (see the module doc)."""
    fig = _figure(8.0, 5.5)
    ax = fig.add_subplot()
    ks = sorted({p.k for c in curves.values() for p in c})
    dense = np.linspace(min(ks), max(ks), 200) if ks else np.zeros(0)
    for name, points in curves.items():
        pts = _finite(points)
        if not pts:
            continue
        k = np.array([p.k for p in pts])
        rms = np.array([p.rms_m for p in pts])
        if name == THEORY:
            ax.plot(k, rms, "--", color="0.3", label=label(name))
            continue
        style = _STYLE.get(name, {})
        fit = fits.get(name)
        # Spread the markers of overlapping curves sideways a little so every bar stays visible.
        offset = 0.04 * (list(curves).index(name) - len(curves) / 2) if len(ks) > 1 else 0.0
        ax.errorbar(
            k + offset, rms, yerr=[p.std_m for p in pts], fmt=str(style.get("marker", "o")), ms=4,
            color=style.get("color"), capsize=2, elinewidth=0.8, label=label(name),
            linestyle="none",
        )  # fmt: skip
        if fit is not None:
            ax.plot(dense, np.polyval(fit, dense), "-", color=style.get("color"), lw=1.2, alpha=0.8)
    ax.set_xlabel("distance to the plane (baselines)")
    ax.set_ylabel("RMS depth error (m)")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def depth_ratio_plot(path: Path, curves: Mapping[str, Sequence[CurvePoint]], title: str) -> Path:
    """Each curve's RMS divided by the Reference's at the same distance (log scale)."""
    fig = _figure(8.0, 4.5)
    ax = fig.add_subplot()
    ref = {p.k: p.rms_m for p in curves.get(REFERENCE, [])}
    for name, points in curves.items():
        if name in (REFERENCE, THEORY):
            continue
        pts = [p for p in _finite(points) if ref.get(p.k, math.nan) > 0]
        if pts:
            style = _STYLE.get(name, {})
            ratio = [p.rms_m / ref[p.k] for p in pts]
            marker = str(style.get("marker", "o"))
            ax.plot(
                [p.k for p in pts],
                ratio,
                "-",
                marker=marker,
                color=style.get("color"),
                ms=4,
                label=label(name),
            )
    ax.axhline(1.0, color="black", lw=1, label="Reference")
    ax.set_yscale("log")
    ax.set_xlabel("distance to the plane (baselines)")
    ax.set_ylabel("RMS error / Reference RMS error")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def matcher_plot(
    path: Path, matchers: Mapping[str, tuple[Sequence[MatcherPoint], float]], title: str
) -> Path:
    """Disparity RMS (all valid pixels and within 1 px), >1 px error fraction and valid
    fraction against distance, one line per matcher (its time per frame in the legend)."""
    fig = _figure(13.0, 4.2)
    axes: list[Axes] = list(fig.subplots(1, 3))
    panels = [
        ("rms_px", "disparity RMS, all valid pixels (px)", "log"),
        ("rms_inlier_px", "disparity RMS within 1 px (px)", "linear"),
        ("valid_frac", "valid fraction", "linear"),
    ]
    for ax, (field, ylabel, scale) in zip(axes, panels, strict=True):
        for name, (points, ms) in matchers.items():
            ax.plot(
                [p.k for p in points], [getattr(p, field) for p in points], "-o", ms=3,
                label=f"{MATCHER_LABELS.get(name, name)}, {ms:.0f} ms",
            )  # fmt: skip
        ax.set_xlabel("distance to the plane (baselines)")
        ax.set_ylabel(ylabel)
        ax.set_yscale(scale)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(title)
    return _save(fig, path)


def difference_montage(
    path: Path,
    reference: NDArray[np.uint8],
    diffs: Mapping[str, tuple[NDArray[np.uint8], float]],
    gain: float,
    title: str,
) -> Path:
    """The Reference image, then each model's contrast-enhanced difference image with its mean
    absolute difference, like the paper's Fig. 6."""
    n = 1 + len(diffs)
    cols = min(4, n)
    rows = math.ceil(n / cols)
    h, w = reference.shape[:2]
    fig = _figure(3.4 * cols, 3.4 * rows * h / w + 0.6)
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    axes[0].imshow(reference, cmap="gray", vmin=0, vmax=255)
    axes[0].set_title("Reference camera", fontsize=9)
    for ax, (name, (diff, mad)) in zip(axes[1:], diffs.items(), strict=False):
        ax.imshow(np.clip(diff.astype(np.float32) * gain, 0, 255), cmap="gray", vmin=0, vmax=255)
        ax.set_title(f"{label(name)}: {mad:.2f}", fontsize=9)
    for ax in axes:
        ax.set_axis_off()
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def coverage_plot(
    path: Path,
    width: int,
    height: int,
    corners: Sequence[NDArray[np.float64]],
    principal_point: tuple[float, float],
    title: str,
) -> Path:
    """Detected corners of every calibration view over the image (one colour per view)."""
    fig = _figure(6.0, 6.0 * height / width + 0.4)
    ax = fig.add_subplot()
    for c in corners:
        ax.plot(c[:, 0], c[:, 1], ".", ms=2)
    ax.plot(*principal_point, "r+", ms=12)
    ax.set_xlim(-0.5, width - 0.5)
    ax.set_ylim(height - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    return _save(fig, path)
