"""Procedural grey patterns for the virtual environment: seeded, periodic (they tile without a
seam) and multi-scale, so stereo matching finds detail at every distance from 2 to 20 baselines.

Every generator takes a ``numpy.random.Generator`` and a tile size ``P`` and returns a float32
image (P, P) in grey levels [0, 255]. A plain checker is deliberately absent: its repeats make
stereo ambiguous.
"""

from __future__ import annotations

import string
from collections.abc import Callable

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["PATTERNS", "spectral_noise"]

F32 = NDArray[np.float32]
Pattern = Callable[[np.random.Generator, int], F32]


def spectral_noise(rng: np.random.Generator, size: int, beta: float = 0.85) -> F32:
    """Periodic gaussian noise (size, size) with amplitude ∝ f^-beta, zero mean, unit std.

    beta = 1 puts equal energy in every octave (scale invariant); a little less favours the fine
    detail the matcher needs at the far end.
    """
    white = rng.standard_normal((size, size))
    spec = np.fft.rfft2(white)
    fy = np.fft.fftfreq(size)[:, None] * size
    fx = np.fft.rfftfreq(size)[None, :] * size
    f = np.hypot(fx, fy)
    f[0, 0] = 1.0
    spec *= f**-beta
    spec[0, 0] = 0.0
    out = np.fft.irfft2(spec, s=(size, size))
    out /= out.std() + 1e-12
    return out.astype(np.float32)


def _finish(img: NDArray[np.floating], mean: float = 128.0, std: float = 55.0) -> F32:
    """Normalise contrast to mean/std grey levels and clip to [0, 255]."""
    a = img.astype(np.float64)
    a = (a - float(a.mean())) / (float(a.std()) + 1e-12) * std + mean
    return np.clip(a, 0.0, 255.0).astype(np.float32)


def _wrapped_offsets(x: float, y: float, reach: float, size: int) -> list[tuple[float, float]]:
    """Copies of a shape at (x, y) with extent ``reach`` needed to tile a size×size canvas."""
    xs = [x] + ([x - size] if x + reach >= size else []) + ([x + size] if x - reach < 0 else [])
    ys = [y] + ([y - size] if y + reach >= size else []) + ([y + size] if y - reach < 0 else [])
    return [(a, b) for a in xs for b in ys]


def noise(rng: np.random.Generator, size: int) -> F32:
    """Scale-invariant value noise: ~11 octaves of equal contrast at 2048 px."""
    return _finish(spectral_noise(rng, size, beta=0.85))


def blobs(rng: np.random.Generator, size: int) -> F32:
    """Dead-leaves discs (radius density ∝ r⁻³, scale invariant) with a little fine noise."""
    # 4 fractional bits: sub-pixel disc positions, so the pattern has no pixel-grid bias.
    shift = 4
    canvas = np.full((size, size), 128, dtype=np.uint8)
    r_min, r_max = max(1.5, size / 500.0), size / 10.0
    mean_area = 2.0 * np.pi * r_min**2 * np.log(r_max / r_min)
    count = int(3.0 * size * size / mean_area)
    # Inverse-CDF sampling of p(r) ∝ r^-3 on [r_min, r_max].
    u = rng.random(count)
    radii = (r_min**-2 - u * (r_min**-2 - r_max**-2)) ** -0.5
    radii = radii[np.argsort(-radii)]  # big ones first, small ones end on top: detail everywhere
    centres = rng.random((count, 2)) * size
    greys = rng.integers(0, 256, count)
    for (x, y), r, g in zip(centres, radii, greys, strict=True):
        for cx, cy in _wrapped_offsets(float(x), float(y), float(r), size):
            cv2.circle(
                canvas,
                (round(cx * (1 << shift)), round(cy * (1 << shift))),
                round(r * (1 << shift)),
                int(g),
                thickness=-1,
                lineType=cv2.LINE_AA,
                shift=shift,
            )
    return _finish(canvas.astype(np.float32) + 12.0 * spectral_noise(rng, size, beta=0.6))


def bricks(rng: np.random.Generator, size: int) -> F32:
    """24 courses of running-bond bricks, each its own shade, mortar joints, weathering noise."""
    rows, per_row = 24, 12
    h, w = size / rows, size / per_row
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64) + 0.5
    course = np.floor(yy / h).astype(np.int64)
    x_shift = np.where(course % 2 == 1, w / 2.0, 0.0)
    col = np.floor(((xx + x_shift) % size) / w).astype(np.int64) % per_row
    shades = rng.uniform(60.0, 200.0, (rows, per_row))
    img = shades[course % rows, col]
    # Mortar: distance to the nearest joint, in brick heights.
    fy = (yy / h) % 1.0
    fx = (((xx + x_shift) % size) / w) % 1.0
    joint = np.minimum(np.minimum(fy, 1.0 - fy) * h, np.minimum(fx, 1.0 - fx) * w) / h
    img = np.where(joint < 0.06, 40.0, img)
    img = img + 28.0 * spectral_noise(rng, size, beta=0.7)
    return _finish(img, std=50.0)


def paper(rng: np.random.Generator, size: int) -> F32:
    """A printed page: random words in several font sizes (headlines to small print) on fibrous
    paper. Letters give the vertical edges stereo needs, at many scales."""
    canvas = np.full((size, size), 235, dtype=np.uint8)
    letters = np.array(list(string.ascii_letters + string.digits))
    fonts = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX)
    y = 0.0
    while y < size:
        # Each line picks a size: a few headlines, mostly body text, some fine print.
        scale = float(
            size / 1024.0 * rng.choice([0.35, 0.5, 0.7, 1.0, 1.6, 2.6], p=[0.2, 0.3, 0.2, 0.15, 0.1, 0.05])
        )
        font = int(rng.choice(fonts))
        thick = max(1, round(scale * 1.6))
        (_, text_h), _ = cv2.getTextSize("Ag", font, scale, thick)
        y += text_h * 1.6
        x = float(rng.uniform(0, size))
        end = x + size
        while x < end:
            word = "".join(rng.choice(letters, int(rng.integers(2, 10))))
            (tw, _), _ = cv2.getTextSize(word, font, scale, thick)
            if x + tw > end:  # would overprint the line's first word after wrapping
                break
            ink = int(rng.integers(0, 90))
            for ox, oy in _wrapped_offsets(x, min(y, size - 1), float(tw + text_h), size):
                cv2.putText(canvas, word, (round(ox), round(oy)), font, scale, ink, thick, cv2.LINE_AA)
            x += tw + text_h * float(rng.uniform(0.5, 1.2))
    fibres = spectral_noise(rng, size, beta=0.5) * 10.0 + spectral_noise(rng, size, beta=1.2) * 14.0
    return _finish(canvas.astype(np.float32) + fibres, mean=150.0, std=60.0)


def checker_noise(rng: np.random.Generator, size: int) -> F32:
    """16×16 checker (floor tiles) whose squares carry their own shade and multi-scale noise."""
    n = 16
    yy, xx = np.mgrid[0:size, 0:size]
    sq_y, sq_x = (yy * n) // size, (xx * n) // size
    parity = ((sq_y + sq_x) % 2).astype(np.float64)
    shade = rng.uniform(-15.0, 15.0, (n, n))[sq_y, sq_x]
    img = 128.0 + 45.0 * (parity - 0.5) * 2.0 + shade + 40.0 * spectral_noise(rng, size, beta=0.8)
    return _finish(img, std=55.0)


PATTERNS: dict[str, Pattern] = {
    "noise": noise,
    "blobs": blobs,
    "bricks": bricks,
    "paper": paper,
    "checker-noise": checker_noise,
}
