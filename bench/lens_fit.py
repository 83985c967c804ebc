"""Fit the honest renderer's lens model (``rig.sim.lens_effects``) to real fisheye images.

Data (``bench.lens_data``): the real ring's four cameras (3 frames each), a second OCamCalib lens
(matsuren, one image) and an uncalibrated stereo pair (sourishg, 29 pairs). Relative field
x = θ/θmax throughout. Printed:

1. **Sharpness against field angle.** Per camera and bin of x, the Gaussian σ (px) of the PSF
   from the 20th percentile of the 10–90 % widths of strong edges (``bench.lens_measure``),
   through the width of synthetic edges of known σ, the median over sectors of azimuth; then
   ``σ(x) = s0 + s1·x^p`` fitted per camera and, for the ring, jointly: s0, s1, p (at least
   :data:`MIN_POWER`) shared and a defocus σ per camera added in quadrature (zero for the
   sharpest). The σ of the ring and
   matsuren lenses also in mrad (σ over the lens's pixels per radian on the axis), to compare
   the two ways of carrying a fit over to another lens.
2. **Rim darkening and exposure.** From points both neighbouring ring cameras see
   (``bench.lens_overlap``): the log brightness ratio is fitted (soft-L1 least squares) with the
   relative illumination ``1 + c1·x² + c2·x⁴`` and a gain and a response exponent γ per camera
   (camera 1's fixed at 1) about a pivot grey level m (the samples' geometric mean),
   ``grey = gain · m · (L · RI(x) / m)^γ``, L the grey level camera 1 would record on its axis.
3. **Noise.** Per camera the noise σ of the flattest 8×8 blocks (10th percentile per bin of 16
   grey levels) and ``σ² = read² + shot·grey`` fitted to them.

The prototype's lens takes the ring's shared curves (functions of x, σ in its own pixels) and,
for its left and right cameras, the defocus, gain (normalised to their mean) and γ of ring
cameras 1 and 2, an adjacent pair like the prototype's.

Run: ``.venv/bin/python -m bench.lens_fit`` (``--quick``: fewer edges; about a minute).
"""

from __future__ import annotations

import argparse
import itertools
import math
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rich.table import Table
from scipy.optimize import least_squares

from bench.common import add_common_arguments, console, finish, machine_info, print_machine
from bench.lens_data import LensCamera, load_lenses, shared_data
from bench.lens_measure import (
    WIDTH_PERCENTILE,
    edge_widths,
    noise_blocks,
    sigma_from_width,
    width_calibration,
)
from bench.lens_overlap import OverlapSamples, ring_overlap

__all__ = ["X_BINS", "fit_blur", "fit_illumination", "fit_noise", "main"]

F64 = NDArray[np.float64]

#: Bins of relative field for the sharpness curve.
X_BINS = np.array([0.0, 0.15, 0.3, 0.45, 0.6, 0.7, 0.8, 0.9, 0.97])
_MIN_EDGES = 15
#: Sectors of azimuth: a lens blurs alike all round its axis, an object near it (the rig's own
#: mount, a hand) in one sector; the median over the sectors keeps the lens's.
SECTORS = 8
#: The blur grows no slower than x² off the axis (field curvature and astigmatism do): it keeps
#: a camera-to-camera spread in sharpness from passing for a rise near the axis.
MIN_POWER = 2.0
MAX_POWER = 30.0


def _bin_sigma(width: F64, azimuth: F64, calibration: tuple[F64, F64]) -> float:
    """σ of one bin: per sector of :data:`SECTORS` with enough edges, the σ of its 20th-percentile
    width; the median over the sectors (NaN for fewer than two)."""
    sector = np.floor((azimuth + math.pi) / (2 * math.pi) * SECTORS).astype(int) % SECTORS
    per_sector = [
        float(np.percentile(width[sector == k], WIDTH_PERCENTILE))
        for k in range(SECTORS)
        if (sector == k).sum() >= _MIN_EDGES
    ]
    if len(per_sector) < 2:
        return math.nan
    return float(sigma_from_width(float(np.median(per_sector)), calibration))


def blur_curve(
    cam: LensCamera, calibration: tuple[F64, F64], rng: np.random.Generator, most: int
) -> tuple[F64, F64, F64]:
    """Bin centres, σ (px) and edge counts of ``cam`` per bin of :data:`X_BINS`."""
    xs, azimuths, widths = [], [], []
    for img in cam.images:
        edges = edge_widths(img, cam.valid, rng, most)
        row, col = edges.y.astype(int), edges.x.astype(int)
        xs.append(cam.x[row, col])
        azimuths.append(cam.azimuth[row, col])
        widths.append(edges.width)
    x, az, w = np.concatenate(xs), np.concatenate(azimuths), np.concatenate(widths)
    centres, sigmas, counts = [], [], []
    for lo, hi in itertools.pairwise(X_BINS):
        sel = (x >= lo) & (x < hi)
        centres.append(float(np.median(x[sel])) if sel.any() else (lo + hi) / 2)
        counts.append(int(sel.sum()))
        sigmas.append(_bin_sigma(w[sel], az[sel], calibration))
    return np.array(centres), np.array(sigmas), np.array(counts, dtype=np.float64)


def _curve(params: F64, x: F64) -> F64:
    s0, s1, p = params
    out: F64 = s0 + s1 * np.clip(x, 0.0, 1.0) ** p
    return out


def fit_blur(curves: list[tuple[F64, F64, F64]]) -> tuple[F64, F64]:
    """Joint fit over cameras: (s0, s1, p) shared and a defocus per camera (0 for the sharpest,
    the camera with the least mean σ); weights √count. Returns (s0, s1, p) and the defocus σs."""
    means = [float(np.mean(s[np.isfinite(s)])) if np.isfinite(s).any() else math.inf for _, s, _ in curves]
    sharpest = int(np.argmin(means))
    others = [i for i in range(len(curves)) if i != sharpest]

    def residual(v: F64) -> F64:
        defocus = np.zeros(len(curves))
        defocus[others] = v[3:]
        out = []
        for i, (x, s, n) in enumerate(curves):
            ok = np.isfinite(s)
            out.append(np.sqrt(n[ok]) * (np.hypot(_curve(v[:3], x[ok]), defocus[i]) - s[ok]))
        return np.concatenate(out)

    start = np.array([0.5, 0.3, 4.0, *([0.3] * len(others))])
    lower = np.array([0.0, 0.0, MIN_POWER, *([0.0] * len(others))])
    upper = np.array([5.0, 5.0, MAX_POWER, *([5.0] * len(others))])
    fit = least_squares(residual, start, bounds=(lower, upper))
    defocus = np.zeros(len(curves))
    defocus[others] = fit.x[3:]
    return fit.x[:3], defocus


def fit_single(curve: tuple[F64, F64, F64]) -> F64:
    """(s0, s1, p) of one camera (NaN without enough edges)."""
    if np.isfinite(curve[1]).sum() < 3:
        return np.full(3, math.nan)
    params, _ = fit_blur([curve])
    return params


def fit_illumination(samples: OverlapSamples, cameras: int) -> dict[str, Any]:
    """Relative illumination (c1, c2), gains and γ per camera (camera 0's 1) from ``samples``."""
    keep = (samples.grey_a > 8) & (samples.grey_b > 8) & (samples.grey_a < 245) & (samples.grey_b < 245)
    a, b = samples.cam_a[keep], samples.cam_b[keep]
    xa, xb = samples.x_a[keep], samples.x_b[keep]
    la, lb = np.log(samples.grey_a[keep]), np.log(samples.grey_b[keep])
    pivot = float(np.mean((la + lb) / 2.0))
    level = (la + lb) / 2.0 - pivot

    def unpack(v: F64) -> tuple[F64, F64, F64]:
        log_gain = np.concatenate([[0.0], v[2 : 1 + cameras]])
        gamma = np.concatenate([[1.0], v[1 + cameras :]])
        return v[:2], log_gain, gamma

    def log_ri(c: F64, x: F64) -> F64:
        x2 = np.clip(x, 0.0, 1.0) ** 2
        out: F64 = np.log(np.maximum(1.0 + c[0] * x2 + c[1] * x2 * x2, 1e-3))
        return out

    def residual(v: F64) -> F64:
        c, log_gain, gamma = unpack(v)
        # log grey = log gain + γ (log L + log RI): the scene's log L is the pair's mean level.
        pred = log_gain[a] - log_gain[b] + (gamma[a] - gamma[b]) * level
        pred += gamma[a] * log_ri(c, xa) - gamma[b] * log_ri(c, xb)
        out: F64 = (la - lb) - pred
        return out

    start = np.array([-0.3, 0.0, *([0.0] * (cameras - 1)), *([1.0] * (cameras - 1))])
    fit = least_squares(residual, start, loss="soft_l1", f_scale=0.05)
    c, log_gain, gamma = unpack(fit.x)
    spread = 1.4826 * float(np.median(np.abs(fit.fun)))
    return {
        "c": c,
        "gain": np.exp(log_gain),
        "gamma": gamma,
        "pivot": math.exp(pivot),
        "points": int(keep.sum()),
        "x_range": np.percentile(np.concatenate([xa, xb]), [5, 95]),
        "robust_sigma": spread,
    }


def fit_noise(cam: LensCamera) -> tuple[float, float, F64, F64]:
    """(read σ, shot) of ``σ² = read² + shot·grey`` and the binned (grey, σ) it was fitted to."""
    means, sigmas = [], []
    for img in cam.images:
        m, s = noise_blocks(img, cam.valid)
        means.append(m)
        sigmas.append(s)
    m, s = np.concatenate(means), np.concatenate(sigmas)
    grey, sigma = [], []
    for lo in range(16, 240, 16):
        sel = (m >= lo) & (m < lo + 16)
        if sel.sum() >= 200:
            grey.append(float(np.median(m[sel])))
            sigma.append(float(np.percentile(s[sel], 10)))
    g, sg = np.array(grey), np.array(sigma)
    (read2, shot), *_ = np.linalg.lstsq(np.stack([np.ones_like(g), g], axis=1), sg**2, rcond=None)
    return math.sqrt(max(read2, 0.0)), max(float(shot), 0.0), g, sg


def _blur_table(cams: list[LensCamera], curves: list[tuple[F64, F64, F64]]) -> Table:
    table = Table(title="PSF σ (px) per relative field x = θ/θmax (20th percentile of edge widths; edges)")
    table.add_column("lens / camera")
    for lo, hi in itertools.pairwise(X_BINS):
        table.add_column(f"{lo:.2f}–{hi:.2f}", justify="right")
    table.add_column("fit s0 + s1·x^p", justify="right")
    for cam, curve in zip(cams, curves, strict=True):
        _, s, n = curve
        s0, s1, p = fit_single(curve)
        cells = [
            f"{v:.2f} ({int(k)})" if np.isfinite(v) else f"– ({int(k)})" for v, k in zip(s, n, strict=True)
        ]
        fit = f"{s0:.2f} + {s1:.2f}·x^{p:.1f}" if np.isfinite(s0) else "too few edges"
        table.add_row(f"{cam.lens} {cam.camera}", *cells, fit)
        if math.isfinite(cam.px_per_rad):
            mrad = [f"{1e3 * v / cam.px_per_rad:.2f}" if np.isfinite(v) else "–" for v in s]
            table.add_row(f"  in mrad ({cam.px_per_rad:.0f} px/rad)", *mrad, "")
    return table


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m bench.lens_fit", description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    args = parser.parse_args(argv)
    most = 5000 if args.quick else 8000
    info = machine_info()
    print_machine(info, "the honest renderer's lens model fitted to real fisheye images")
    rng = np.random.default_rng(0)
    cams = load_lenses()
    calibration = width_calibration(rng, images=1 if args.quick else 3)
    console.print(
        "edge width (20th percentile, px) of synthetic edges of σ: "
        + ", ".join(f"{s:g}→{w:.2f}" for s, w in zip(*calibration, strict=True))
    )
    curves = [blur_curve(cam, calibration, rng, most) for cam in cams]
    console.print(_blur_table(cams, curves))
    ring = [i for i, c in enumerate(cams) if c.lens == "ring"]
    shared, defocus = fit_blur([curves[i] for i in ring])
    console.print(
        f"ring, joint: σ(x) = hypot({shared[0]:.3f} + {shared[1]:.3f}·x^{shared[2]:.2f}, defocus), "
        f"defocus σ per camera {', '.join(f'{d:.3f}' for d in defocus)} px"
    )
    ring_cams = [cams[i] for i in ring]
    overlap = fit_illumination(
        ring_overlap(ring_cams, shared_data() / "ring_sweepnet_indoor" / "poses.txt"), 4
    )
    c1, c2 = overlap["c"]
    ri = ", ".join(f"x={x:.2f}: {1 + c1 * x * x + c2 * x**4:.3f}" for x in (0.25, 0.5, 0.75, 0.9, 1.0))
    gains_text = ", ".join(f"{g:.3f}" for g in overlap["gain"])
    gammas_text = ", ".join(f"{g:.3f}" for g in overlap["gamma"])
    console.print(
        f"relative illumination 1 + {c1:.4f}·x² + {c2:.4f}·x⁴ ({ri}); about grey {overlap['pivot']:.1f}: "
        f"gains {gains_text}; γ {gammas_text} "
        f"({overlap['points']} points at x {overlap['x_range'][0]:.2f}–{overlap['x_range'][1]:.2f} "
        f"(5th–95th percentile), robust σ of the log ratio {overlap['robust_sigma']:.3f})"
    )
    noise = {}
    for cam in cams:
        read, shot, _, _ = fit_noise(cam)
        noise[f"{cam.lens} {cam.camera}"] = (read, shot)
        console.print(f"noise {cam.lens} {cam.camera}: σ² = {read:.3f}² + {shot:.4f}·grey")
    ring_noise = np.median([noise[f"ring {c.camera}"] for c in ring_cams], axis=0)
    gains = overlap["gain"][:2] / overlap["gain"][:2].mean()
    console.print(
        "the prototype's HONEST_LENS: "
        f"blur_centre_px={shared[0]:.3f}, blur_rim_px={shared[1]:.3f}, blur_power={shared[2]:.2f}, "
        f"illumination=({c1:.4f}, {c2:.4f}), response_pivot={overlap['pivot']:.1f}, "
        f"read_noise={ring_noise[0]:.3f}, shot_noise={ring_noise[1]:.4f}, "
        f"exposures: left gain {gains[0]:.3f} γ {overlap['gamma'][0]:.3f} defocus {defocus[0]:.3f}, "
        f"right gain {gains[1]:.3f} γ {overlap['gamma'][1]:.3f} defocus {defocus[1]:.3f}"
    )
    results = {
        "curves": {
            f"{c.lens} {c.camera}": {"x": cur[0], "sigma_px": cur[1], "edges": cur[2]}
            for c, cur in zip(cams, curves, strict=True)
        },
        "ring_blur": {"s0": shared[0], "s1": shared[1], "p": shared[2], "defocus": defocus},
        "illumination": overlap,
        "noise": noise,
    }
    return finish("lens_fit", info, _plain(results), args.json, None)


def _plain(value: Any) -> Any:
    """``value`` with numpy arrays and scalars as lists and numbers (for the JSON output)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    return value


if __name__ == "__main__":
    t0 = time.monotonic()
    main()
    console.print(f"took {time.monotonic() - t0:.0f} s")
