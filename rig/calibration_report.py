"""Pictures of calibration residuals: where over the image the model misses the detections.

One panel per camera: each corner's residual (projection − detection) drawn as an arrow at the
detected position (scaled to be visible, scale in the title), coloured by its length; below it,
the residual length against the distance from the principal point, which shows at a glance
whether the rim of a fisheye image (corners past 90° off axis) is modelled as well as the centre.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["ResidualPanel", "save_residual_plot"]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class ResidualPanel:
    """One camera's residuals: detections (N, 2) and residuals (N, 2) per view."""

    title: str
    image_size: tuple[int, int]  # (width, height)
    principal_point: tuple[float, float]
    points: Sequence[F64]
    residuals: Sequence[F64]


def save_residual_plot(path: str | Path, panels: Sequence[ResidualPanel]) -> Path:
    """Write a PNG with one column per panel; returns the path. Raises OSError if it cannot
    be written."""
    out = Path(path)
    # matplotlib only here: every `rig calibrate` command imports this module, few draw.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    fig = Figure(figsize=(6.0 * len(panels), 8.0), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, len(panels), squeeze=False, height_ratios=[3, 1])
    for col, panel in enumerate(panels):
        pts = np.concatenate(panel.points) if panel.points else np.zeros((0, 2))
        res = np.concatenate(panel.residuals) if panel.residuals else np.zeros((0, 2))
        err = np.linalg.norm(res, axis=1)
        w, h = panel.image_size
        rms = float(np.sqrt(np.mean(err**2))) if err.size else float("nan")
        # Arrows about 1/25 of the image width for the largest residual.
        scale = (w / 25.0) / max(float(err.max()) if err.size else 1.0, 1e-9)
        ax = axes[0, col]
        ax.set_title(f"{panel.title}: RMS {rms:.3f} px, {len(err)} corners\narrows x{scale:.0f}")
        ax.set_xlim(-0.5, w - 0.5)
        ax.set_ylim(h - 0.5, -0.5)
        ax.set_aspect("equal")
        ax.add_patch(Rectangle((-0.5, -0.5), w, h, fill=False, edgecolor="0.5"))
        if err.size:
            q = ax.quiver(
                pts[:, 0], pts[:, 1], res[:, 0] * scale, res[:, 1] * scale, err,
                angles="xy", scale_units="xy", scale=1.0, cmap="viridis", width=0.003,
            )  # fmt: skip
            fig.colorbar(q, ax=ax, label="residual (px)", shrink=0.8)
        ax.plot(*panel.principal_point, "r+", markersize=12)
        ax.set_xlabel("u (px)")
        ax.set_ylabel("v (px)")
        radius = np.linalg.norm(pts - np.asarray(panel.principal_point), axis=1)
        ax2 = axes[1, col]
        ax2.scatter(radius, err, s=4)
        ax2.set_xlabel("distance from principal point (px)")
        ax2.set_ylabel("residual (px)")
        ax2.grid(True, alpha=0.3)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, format="png")
    return out
