"""The floor in a stereo pair's range, and the right camera's rotation that puts it flat at a
known height (docs/rectification.md, "Vergence from the floor").

A floor pixel of the left rectified view has a ray ``a`` from the left optical centre; the
matcher's disparity ``d`` gives the right view's pixel ``u − d`` on the same row, a ray ``q``
from the right centre. Where the floor is the plane ``n·p = −h`` (``n`` the rig's up, ``h`` the
height of the rig's origin above it), the left ray meets it at ``P``, and the right ray should
point at ``P``: the **residual** is the azimuth of ``q`` (its angle out of the plane
perpendicular to the baseline, the quantity a disparity measures) less the azimuth of
``P − c_right``, in radians (× ``fx``: disparity pixels).

Turning the right camera by a small rotation ``Ω`` (rig frame) turns ``q``. About the baseline
(the rectified x) it changes no azimuth: the floor says nothing about it (the vertical disparity
does). About the rectified y (vergence) it shifts the azimuth of the row at elevation φ by
``Ω_y cos φ``, about the rectified z (the look direction) by ``−Ω_z sin φ``: a floor seen over a
range of elevations constrains both. The floor's normal is the given up, not fitted: to the
floor, a pitch of the rig relative to it looks almost exactly like vergence (both tilt the floor
ahead), so the up direction must come from elsewhere (the mount's geometry, an IMU). A turn of
the whole rig about the up axis, or a slide along the floor, changes nothing the floor shows.
:func:`fit_plane` measures the floor as the range shows it (height and tilt free, no turn).

Floor pixels are found robustly: rays at least ``min_depression_deg`` below the horizon whose
disparity is within ``window_deg`` of the known floor's, then RANSAC on the linearised model,
then a robust least-squares fit on its inliers. Uncertainties are cluster-robust: the pixels of
one ``cell_px`` square share their matching errors (SGBM's windows, the median filter), so the
cells, not the pixels, are the independent samples.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from rig.errors import RectificationError
from rig.rectified import RectifiedPair

__all__ = [
    "FloorFit",
    "FloorGeometry",
    "FloorOptions",
    "FloorSamples",
    "fit_floor",
    "fit_plane",
    "floor_height",
    "floor_params",
    "floor_range",
    "floor_residuals",
    "floor_samples",
    "pixel_samples",
]

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]
Mask = NDArray[np.bool_]

#: Parameter vector: right camera's turn about the rectified y and z, floor tilt about two
#: horizontal axes (radians), floor height (m).
OMEGA_Y, OMEGA_Z, TILT_1, TILT_2, HEIGHT = range(5)
_STEP = 1e-6  # finite-difference step of the linearisation (radians, metres)


@dataclass(frozen=True)
class FloorOptions:
    """``min_depression_deg``: floor rays point at least this far below the horizon;
    ``window_deg``: a candidate's disparity is within this angle of the known floor's (the
    largest correction found); ``inlier_px``: the consensus band in disparity pixels;
    ``stride``: every stride-th pixel of the view in each direction; ``cell_px``: the side of
    the cells whose pixels share errors; ``min_points``/``min_cells``: fewer inliers or cells
    is no floor."""

    min_depression_deg: float = 10.0
    window_deg: float = 1.0
    inlier_px: float = 1.0
    stride: int = 3
    cell_px: int = 16
    min_points: int = 2000
    min_cells: int = 40
    ransac_iterations: int = 300
    seed: int = 0


@dataclass(frozen=True)
class FloorGeometry:
    """The pair's frame in the rig: centres, the rectified axes ``x`` (baseline), ``y``, ``z``,
    the rig's ``up`` and two horizontal axes ``e1``, ``e2`` for the floor's tilt; ``fx`` the
    view's pixels per radian."""

    c_left: F64
    c_right: F64
    x: F64
    y: F64
    z: F64
    up: F64
    e1: F64
    e2: F64
    fx: float

    @classmethod
    def of(cls, pair: RectifiedPair, up: F64) -> FloorGeometry:
        R = pair.R_rig_rect
        u = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
        e1 = R[:, 0] - (R[:, 0] @ u) * u
        if np.linalg.norm(e1) < 1e-6:  # a vertical baseline: any horizontal axis
            e1 = R[:, 2] - (R[:, 2] @ u) * u
        e1 /= np.linalg.norm(e1)
        c_l, c_r = (pair.T_rig_rect[n][:3, 3].copy() for n in (pair.left, pair.right))
        return cls(c_l, c_r, R[:, 0].copy(), R[:, 1].copy(), R[:, 2].copy(), u, e1, np.cross(u, e1), pair.fx)

    def omega(self, params: F64) -> F64:
        """The right camera's turn (rotation vector, rig frame) of ``params``."""
        out: F64 = params[OMEGA_Y] * self.y + params[OMEGA_Z] * self.z
        return out

    def normal(self, params: F64) -> F64:
        """The floor's unit normal (up) of ``params``."""
        tilt = params[TILT_1] * self.e1 + params[TILT_2] * self.e2
        out: F64 = Rotation.from_rotvec(tilt).apply(self.up)
        return out


@dataclass(frozen=True)
class FloorSamples:
    """Pixels of one or more frames: left rays ``a`` and right rays ``q`` (N, 3, rig frame, the
    calibration's), the range along ``a`` (N,), the left view's pixel (N, 2), its frame (N,)
    and its cell (N,: same frame and ``cell_px`` square)."""

    a: F64
    q: F64
    range: F64
    pixel: F64
    frame: NDArray[np.intp]
    cell: NDArray[np.int64]

    def __len__(self) -> int:
        return len(self.range)

    def select(self, keep: Mask) -> FloorSamples:
        return FloorSamples(
            self.a[keep], self.q[keep], self.range[keep], self.pixel[keep], self.frame[keep], self.cell[keep]
        )

    @classmethod
    def concat(cls, parts: Sequence[FloorSamples]) -> FloorSamples:
        return cls(
            np.concatenate([p.a for p in parts]),
            np.concatenate([p.q for p in parts]),
            np.concatenate([p.range for p in parts]),
            np.concatenate([p.pixel for p in parts]),
            np.concatenate([p.frame for p in parts]),
            np.concatenate([p.cell for p in parts]),
        )


def _azimuth(v: F64, x: F64) -> F64:
    out: F64 = np.arcsin(np.clip((v @ x) / np.linalg.norm(v, axis=1), -1.0, 1.0))
    return out


def floor_range(geo: FloorGeometry, s: FloorSamples, params: F64) -> F64:
    """The range (N,) along each sample's left ray to the floor of ``params`` (NaN: it misses)."""
    n = geo.normal(params)
    down = s.a @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-params[HEIGHT] - geo.c_left @ n) / down
    out: F64 = np.where((down < 0) & (t > 0), t, np.nan)
    return out


def floor_residuals(geo: FloorGeometry, s: FloorSamples, params: F64) -> F64:
    """Each sample's residual (radians): the azimuth of its right ray turned by ``params``'s Ω
    less that of the floor point of its left ray seen from the right centre (see the module
    doc). A left ray that misses the floor (level or up) gets π."""
    t = floor_range(geo, s, params)
    hits = np.isfinite(t)
    P = geo.c_left + np.where(hits, t, 1.0)[:, None] * s.a
    w = Rotation.from_rotvec(geo.omega(params)).apply(s.q)
    out: F64 = np.where(hits, _azimuth(w, geo.x) - _azimuth(P - geo.c_right, geo.x), math.pi)
    return out


def pixel_samples(
    pair: RectifiedPair,
    range_m: F32,
    disparity: F32,
    rows: NDArray[np.intp],
    cols: NDArray[np.intp],
    index: int = 0,
    cell_px: int = 16,
) -> FloorSamples:
    """The samples of the left view's pixels (``rows``, ``cols``) of one frame that have range."""
    cam = pair.camera
    d = disparity[rows, cols].astype(np.float64)
    r = range_m[rows, cols].astype(np.float64)
    ok = np.isfinite(d) & np.isfinite(r) & (d > 0)
    rows, cols, d, r = rows[ok], cols[ok], d[ok], r[ok]
    left, valid_l = cam.unproject(np.stack([cols, rows], axis=1).astype(np.float64), in_image=False)
    right, valid_r = cam.unproject(np.stack([cols - d, rows], axis=1), in_image=False)
    keep = valid_l & valid_r
    R = pair.R_rig_rect
    per_row = -(-cam.width // cell_px)
    cell = index * 1_000_000 + (rows // cell_px) * per_row + cols // cell_px
    return FloorSamples(
        left[keep] @ R.T,
        right[keep] @ R.T,
        r[keep],
        np.stack([cols, rows], axis=1)[keep].astype(np.float64),
        np.full(int(keep.sum()), index, dtype=np.intp),
        cell[keep].astype(np.int64),
    )


def floor_samples(
    pair: RectifiedPair,
    range_m: F32,
    disparity: F32,
    geo: FloorGeometry,
    height_m: float,
    options: FloorOptions,
    index: int = 0,
) -> FloorSamples:
    """The floor candidates of one frame: valid pixels (every ``stride``-th) whose ray points at
    least ``min_depression_deg`` below the horizon and whose disparity is within
    ``window_deg`` of the known floor's (residual at no correction)."""
    cam = pair.camera
    rows, cols = np.mgrid[0 : cam.height : options.stride, 0 : cam.width : options.stride]
    s = pixel_samples(pair, range_m, disparity, rows.ravel(), cols.ravel(), index, options.cell_px)
    s = s.select(-(s.a @ geo.up) > math.sin(math.radians(options.min_depression_deg)))
    e0 = floor_residuals(geo, s, floor_params(height_m))
    return s.select(np.abs(e0) < math.radians(options.window_deg))


def floor_params(height_m: float) -> F64:
    """The parameters of a floor ``height_m`` below the rig's origin, square to up, no turn."""
    p = np.zeros(5)
    p[HEIGHT] = height_m
    return p


@dataclass(frozen=True)
class FloorFit:
    """``params`` (5: Ω_y, Ω_z, tilt 1, tilt 2 in radians, height m) and their 1σ (0 where not
    fitted); ``inliers`` (N,) of the samples; ``residual_px`` the inliers' median |residual|;
    ``correlation`` of Ω_y and Ω_z; ``cells`` the inliers' cells."""

    params: F64
    sigma: F64
    inliers: Mask
    residual_px: float
    correlation: float
    cells: int

    @property
    def omega_deg(self) -> F64:
        """The right camera's turn about the rectified y and z (degrees)."""
        out: F64 = np.degrees(self.params[[OMEGA_Y, OMEGA_Z]])
        return out

    @property
    def omega_sigma_deg(self) -> F64:
        out: F64 = np.degrees(self.sigma[[OMEGA_Y, OMEGA_Z]])
        return out

    @property
    def tilt_deg(self) -> F64:
        out: F64 = np.degrees(self.params[[TILT_1, TILT_2]])
        return out


def _jacobian(geo: FloorGeometry, s: FloorSamples, params: F64, free: Sequence[int]) -> F64:
    cols = []
    for k in free:
        hi, lo = params.copy(), params.copy()
        hi[k] += _STEP
        lo[k] -= _STEP
        cols.append((floor_residuals(geo, s, hi) - floor_residuals(geo, s, lo)) / (2 * _STEP))
    return np.stack(cols, axis=1)


def _ransac(geo: FloorGeometry, s: FloorSamples, start: F64, free: list[int], opts: FloorOptions) -> Mask:
    """Inliers of the best consensus of the model linearised at ``start``."""
    e0 = floor_residuals(geo, s, start)
    J = _jacobian(geo, s, start, free)
    thr = opts.inlier_px / geo.fx
    rng = np.random.default_rng(opts.seed)
    k = 2 * len(free)
    best = np.abs(e0) < thr
    for _ in range(opts.ransac_iterations):
        pick = rng.choice(len(s), size=k, replace=False)
        step, *_ = np.linalg.lstsq(J[pick], -e0[pick], rcond=None)
        inl = np.abs(e0 + J @ step) < thr
        if inl.sum() > best.sum():
            best = inl
    for _ in range(3):  # local optimisation: refit on the consensus, recount
        step, *_ = np.linalg.lstsq(J[best], -e0[best], rcond=None)
        best = np.abs(e0 + J @ step) < thr
    return best


def _solve(geo: FloorGeometry, s: FloorSamples, start: F64, free: list[int], thr: float) -> F64:
    def residuals(x: F64) -> F64:
        p = start.copy()
        p[free] = x
        return floor_residuals(geo, s, p)

    sol = least_squares(residuals, start[free], loss="soft_l1", f_scale=thr / 2, x_scale=0.01)
    out = start.copy()
    out[free] = sol.x
    return out


def _cluster_sigma(J: F64, e: F64, cells: NDArray[np.int64]) -> tuple[F64, F64]:
    """1σ and covariance of a least-squares fit with errors shared within ``cells``."""
    bread = np.linalg.pinv(J.T @ J)
    _, idx = np.unique(cells, return_inverse=True)
    scores = np.zeros((idx.max() + 1, J.shape[1]))
    np.add.at(scores, idx, J * e[:, None])
    cov = bread @ (scores.T @ scores) @ bread
    return np.sqrt(np.diag(cov)), cov


def _no_floor(found: str, height_m: float, opts: FloorOptions) -> RectificationError:
    return RectificationError(
        f"no floor in view: {found} a floor {height_m:.3f} m down, need {opts.min_points} pixels "
        f"in {opts.min_cells} cells of {opts.cell_px} px (is the floor in view, and its height right?)"
    )


def _result(geo: FloorGeometry, s: FloorSamples, params: F64, inliers: Mask, free: list[int]) -> FloorFit:
    """The fit ``params`` with its 1σ and figures on the ``inliers``."""
    inl = s.select(inliers)
    e = floor_residuals(geo, inl, params)
    sig, cov = _cluster_sigma(_jacobian(geo, inl, params, free), e, inl.cell)
    sigma = np.zeros(5)
    sigma[free] = sig
    corr = 0.0
    if OMEGA_Y in free and OMEGA_Z in free:
        iy, iz = free.index(OMEGA_Y), free.index(OMEGA_Z)
        corr = float(cov[iy, iz] / math.sqrt(cov[iy, iy] * cov[iz, iz]))
    cells = len(np.unique(inl.cell))
    return FloorFit(params, sigma, inliers, float(np.median(np.abs(e))) * geo.fx, corr, cells)


def fit_floor(geo: FloorGeometry, s: FloorSamples, height_m: float, options: FloorOptions) -> FloorFit:
    """The right camera's turn about the rectified y and z that puts the samples' floor at
    ``height_m`` below the rig's origin, square to ``geo.up`` (see the module doc): RANSAC, then
    a robust fit on its consensus, twice. RectificationError when the samples hold no floor."""
    if len(s) < options.min_points:
        raise _no_floor(f"{len(s)} pixels below the horizon near", height_m, options)
    free = [OMEGA_Y, OMEGA_Z]
    thr = options.inlier_px / geo.fx
    inliers = _ransac(geo, s, floor_params(height_m), free, options)
    params = floor_params(height_m)
    for _ in range(2):
        params = _solve(geo, s.select(inliers), params, free, thr)
        inliers = np.abs(floor_residuals(geo, s, params)) < thr
    cells = len(np.unique(s.cell[inliers]))
    if inliers.sum() < options.min_points or cells < options.min_cells:
        raise _no_floor(f"{int(inliers.sum())} pixels in {cells} cells agree on", height_m, options)
    turn_deg = math.degrees(math.hypot(params[OMEGA_Y], params[OMEGA_Z]))
    if turn_deg > options.window_deg:
        # The candidates were chosen within window_deg of the floor: a larger turn fits
        # something else (a wall can be bent onto a floor by a few degrees), not this floor.
        raise _no_floor(
            f"the pixels agree only after a {turn_deg:.2f}° turn (over {options.window_deg:g}°) on",
            height_m,
            options,
        )
    return _result(geo, s, params, inliers, free)


def fit_plane(geo: FloorGeometry, s: FloorSamples, height_m: float, options: FloorOptions) -> FloorFit:
    """The plane the samples' range lies on as it is (no turn; height and tilt free, started
    from a floor at ``height_m``), robust, over all of them: ``residual_px`` is how flat the
    range is. The samples are the floor already (a :func:`fit_floor`'s inliers)."""
    free = [HEIGHT, TILT_1, TILT_2]
    params = _solve(geo, s, floor_params(height_m), free, options.inlier_px / geo.fx)
    return _result(geo, s, params, np.ones(len(s), dtype=bool), free)


def floor_height(
    geo: FloorGeometry, s: FloorSamples, options: FloorOptions, heights: F64 | None = None
) -> FloorFit:
    """The floor the samples (every pixel below the horizon) show when its height is not known:
    the height of ``heights`` (default 0.1–10 m in 2 % steps) on which most of them agree within
    twice ``inlier_px``, then the plane (:func:`fit_plane`) of those that agree with it.
    RectificationError when fewer than ``min_points`` agree."""
    grid = np.geomspace(0.1, 10.0, 233) if heights is None else np.asarray(heights, dtype=np.float64)
    band = 2.0 * options.inlier_px / geo.fx
    counts = [np.count_nonzero(np.abs(floor_residuals(geo, s, floor_params(h))) < band) for h in grid]
    best = float(grid[int(np.argmax(counts))])
    agree = np.abs(floor_residuals(geo, s, floor_params(best))) < band
    if agree.sum() < options.min_points:
        raise _no_floor(f"at most {int(agree.sum())} pixels agree on", best, options)
    plane = fit_plane(geo, s.select(agree), best, options)
    agree = np.abs(floor_residuals(geo, s, plane.params)) < band
    return fit_plane(geo, s.select(agree), float(plane.params[HEIGHT]), options)
