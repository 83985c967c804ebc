"""The one colour scale of depth and range in metres: the service's colour depth (``/depth/colorized``,
``/stream.mjpg``, the dashboard's colour bar) and ``rig process --preview`` use it alike.

Turbo on a log scale between a fixed ``near_m`` and ``far_m`` (``server.color_range_m``, by default
:data:`DEFAULT_RANGE_M`): ``near_m`` and nearer are turbo's dark red end, ``far_m`` and farther its
dark blue end, invalid pixels black. Fixed, not per frame, so that a colour means the same distance
on every frame and in every tool; log, so that a hand at 0.4 m and a wall at 6 m are both readable.
:meth:`DepthColors.ticks` gives the labels of a colour bar (1-2-5 steps in metres, plus both ends),
:meth:`DepthColors.legend` draws one for images such as the preview.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["DEFAULT_RANGE_M", "DepthColors", "colorize_depth", "metres_label"]

F32 = NDArray[np.float32]
U8 = NDArray[np.uint8]

#: The colour scale's range (near, far) in metres when none is configured.
DEFAULT_RANGE_M: tuple[float, float] = (0.3, 8.0)
_STEPS = (1.0, 2.0, 5.0)


def metres_label(metres: float) -> str:
    """``0.3 m``, ``1 m``, ``12 m``: a tick's label (two significant digits at most)."""
    return f"{float(f'{metres:.2g}'):g} m"


@dataclass(frozen=True)
class DepthColors:
    """The colour scale between ``near_m`` and ``far_m`` (0 < near < far), log in metres."""

    near_m: float = DEFAULT_RANGE_M[0]
    far_m: float = DEFAULT_RANGE_M[1]

    def __post_init__(self) -> None:
        if not 0.0 < self.near_m < self.far_m:
            raise ValueError(f"colour range must be 0 < near < far, got {self.near_m}, {self.far_m}")

    def position(self, metres: float | NDArray[np.floating]) -> NDArray[np.float64]:
        """Where ``metres`` lies on the scale: 0 at ``near_m``, 1 at ``far_m`` (log), clipped."""
        lo, hi = math.log(self.near_m), math.log(self.far_m)
        t = (np.log(np.asarray(metres, dtype=np.float64)) - lo) / (hi - lo)
        return np.asarray(np.clip(t, 0.0, 1.0))

    def colorize(self, depth: F32) -> U8:
        """BGR (H, W, 3) of depth or range (H, W) float32 m; NaN, ≤ 0 and inf black."""
        d = np.asarray(depth, dtype=np.float32)
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(d) & (d > 0)
        logd = np.log(np.where(valid, d, np.float32(self.far_m)))
        lo, hi = np.float32(math.log(self.near_m)), np.float32(math.log(self.far_m))
        t = np.clip((hi - logd) / (hi - lo), 0.0, 1.0)  # 1 = near (turbo's red end)
        gray = np.rint(t * 255.0).astype(np.uint8)
        out = np.asarray(cv2.applyColorMap(gray, cv2.COLORMAP_TURBO), dtype=np.uint8)
        out[~valid] = 0
        return out

    def palette(self, steps: int = 256) -> U8:
        """(steps, 3) RGB from ``near_m`` to ``far_m``, evenly in log metres: the colour bar."""
        metres = np.exp(np.linspace(math.log(self.near_m), math.log(self.far_m), steps))
        bgr = self.colorize(metres.astype(np.float32)[None, :])[0]
        return np.ascontiguousarray(bgr[:, ::-1])

    def ticks(self) -> list[float]:
        """The colour bar's labelled distances (m): both ends and the 1-2-5 steps between them
        that are not too close to an end (a tenth of the scale) to read."""
        values = [self.near_m]
        decade = 10.0 ** math.floor(math.log10(self.near_m))
        while decade <= self.far_m:
            for step in _STEPS:
                m = float(f"{step * decade:.6g}")
                t = float(self.position(m))
                if self.near_m < m < self.far_m and 0.1 <= t <= 0.9:
                    values.append(m)
            decade *= 10.0
        return [*values, self.far_m]

    def legend(self, height: int, width: int = 72) -> U8:
        """BGR (height, width, 3) colour bar for an image of ``height`` rows: near at the top, a
        label in metres at each tick."""
        bar_w = max(8, width // 4)
        rows = np.linspace(0.0, 1.0, height)
        metres = np.exp(np.log(self.near_m) + rows * (math.log(self.far_m) - math.log(self.near_m)))
        column = self.colorize(metres.astype(np.float32)[:, None])
        out = np.zeros((height, width, 3), np.uint8)
        out[:, :bar_w] = column
        scale = max(0.3, min(0.5, height / 900.0))
        for m in self.ticks():
            y = round(float(self.position(m)) * (height - 1))
            cv2.line(out, (0, y), (bar_w + 3, y), (255, 255, 255), 1)
            text_y = min(max(y + 4, 10), height - 3)
            cv2.putText(
                out, metres_label(m), (bar_w + 5, text_y), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1
            )
        return out


def colorize_depth(depth: F32, near_m: float, far_m: float) -> U8:
    """:meth:`DepthColors.colorize` of ``depth`` between ``near_m`` and ``far_m``."""
    return DepthColors(near_m, far_m).colorize(depth)
