"""Model-aware chessboard corner refinement: X-junctions located where a fisheye does not bend them.

On a fisheye image a chessboard's edges are curves, and a corner detector that assumes straight
edges (``cv2.findChessboardCornersSB``'s ACCURACY step, ``cv2.cornerSubPix``) is pulled towards
their concave side: on renders with exact truth SB is ~0.1 px RMS off the true corners and
~0.07 px radially inwards past 60° off axis. Given a lens model, every corner is instead located
in a small *local pinhole view* centred on its ray. There the board's edges are straight lines
through the corner (a pinhole maps 3D lines to lines), so the X-junction is point-symmetric,
``I(c + x) = I(c − x)`` for every offset ``x`` inside the four squares around the corner, at any
tilt of the board and for any symmetric blur. The corner is the centre of that symmetry: Gauss-
Newton on ``Σ w(x) (I(c + x) − I(c − x) − (k·x) (I(c + x) + I(c − x)))²`` over the shift of ``c``
and an illumination gradient ``k`` (vignetting, uneven light), the view re-centred on the new ray
after every step. The image is sampled at ``model.project`` of the view's rays (valid past 90°
off axis) by bilinear interpolation in float64 (``cv2.remap`` quantises positions to 1/32 px).

:func:`refine_corners_local` refines one image's corners; :func:`refine_views` refines a set of
views and collects the corners it leaves out. Shapes: image (H, W) or (H, W, 3); corners (N, 2)
px (NaN rows = not detected); object points (N, 3) on a planar grid (board frame, z = 0).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypeAlias

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.errors import CalibrationError, CalibrationFileError
from calibration.models.base import CameraModel

__all__ = [
    "BLUR_SIGMA_PX",
    "MAX_RADIUS_PX",
    "CornerRefinement",
    "ImageSource",
    "RefinementReport",
    "RejectedCorner",
    "board_neighbours",
    "load_grey",
    "refine_corners_local",
    "refine_views",
]

F64 = NDArray[np.float64]
Mask = NDArray[np.bool_]
# An image as an array, or the path of an image file (read when needed, as grey).
ImageSource: TypeAlias = "NDArray[np.generic] | str | os.PathLike[str]"

# Largest window radius (local px): enough samples for ~0.02 px, cheap to sample.
MAX_RADIUS_PX = 10.0
# Gaussian pre-blur (px) smoothing the pixel grid's staircase for the bilinear samples. It costs
# a little bias: an illumination gradient k (relative, per px) shifts a corner by ~σ²k, and the
# blur, round in the image, is not quite round in the local view (measured: ≤ 0.003 px).
BLUR_SIGMA_PX = 0.7
# Smallest usable window radius (local px): fewer samples cannot average the pixel grid out.
MIN_RADIUS_PX = 2.5
# Window radius as a fraction of the distance from the corner to the nearest far square edge;
# the rest is margin for that edge's blur and the error of the start point.
_RADIUS_FRACTION = 0.75
# Gaussian weight's sigma as a fraction of the window radius (weights are 0 outside it).
_WEIGHT_SIGMA_FRACTION = 0.7
# Gauss-Newton stops when a corner's step is below this (local px); steps are capped at 1 px.
_STEP_TOL = 1e-4
_MAX_ITER = 15
# A corner that ends further than this fraction of its window from its start is not trusted.
_MAX_MOVE_FRACTION = 0.5
# Minimum grey-level contrast (weighted std of the window) of a usable X-junction.
_MIN_CONTRAST = 4.0
# Symmetry residual (RMS, after the fit) relative to the window's contrast above which the
# window holds no X-junction (occluded, a wrong match, or a lens model far from the truth).
_MAX_ASYMMETRY = 0.25


@dataclass(frozen=True)
class CornerRefinement:
    """Result of :func:`refine_corners_local` for one image.

    ``corners`` (N, 2): refined pixels, NaN where the input was NaN or refinement failed;
    ``shift`` (N,): distance from the input corner (px), NaN likewise; ``asymmetry`` (N,): RMS
    symmetry residual over contrast at the solution; ``reasons``: corner index -> why it failed.
    """

    corners: F64
    shift: F64
    asymmetry: F64
    reasons: dict[int, str]

    @property
    def ok(self) -> Mask:
        return np.asarray(np.isfinite(self.corners).all(axis=1))


def board_neighbours(object_points: ArrayLike) -> NDArray[np.intp]:
    """Indices (N, 4) of each corner's grid neighbours along board +x, −x, +y, −y (−1 = none)
    for a planar grid board (z = 0) with equal spacing along x and y."""
    X = np.asarray(object_points, dtype=np.float64).reshape(-1, 3)
    if len(X) < 4 or not np.isfinite(X).all() or not np.allclose(X[:, 2], 0.0):
        raise CalibrationError("corner refinement needs a planar board (finite object points with z = 0)")
    d = X[None, :, :2] - X[:, None, :2]  # (N, N, 2): from corner i to corner j
    dist = np.linalg.norm(d, axis=2)
    spacing = float(np.min(dist[dist > 0]))
    out = np.full((len(X), 4), -1, dtype=np.intp)
    for k, step in enumerate(([1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0])):
        hit = np.linalg.norm(d - spacing * np.asarray(step), axis=2) < 1e-6 * spacing
        has = hit.any(axis=1)
        out[has, k] = np.argmax(hit[has], axis=1)
    if (out[:, :2] < 0).all(axis=1).any() or (out[:, 2:] < 0).all(axis=1).any():
        raise CalibrationError("corner refinement needs a grid board: a corner has no neighbour along x or y")
    return out


def load_grey(source: ImageSource) -> F64:
    """A grey float64 image (H, W) from an array (grey, BGR or BGRA) or an image file."""
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise CalibrationFileError(path, "cannot be read as an image")
        return np.asarray(img, dtype=np.float64)
    img = np.asarray(source)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        img = cv2.cvtColor(img.astype(np.float32) if img.dtype == np.float64 else img, code)
    if img.ndim != 2:
        raise CalibrationError(f"corner refinement needs a grey or BGR image, got shape {img.shape}")
    return np.asarray(img, dtype=np.float64)


def _bilinear(img: F64, u: F64, v: F64) -> tuple[F64, Mask]:
    """Values at (u, v) (equal shapes) and whether the four neighbouring pixels exist."""
    h, w = img.shape
    ok = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u <= w - 1) & (v <= h - 1)
    uc, vc = np.where(ok, u, 0.0), np.where(ok, v, 0.0)
    u0 = np.minimum(np.floor(uc).astype(np.intp), w - 2)
    v0 = np.minimum(np.floor(vc).astype(np.intp), h - 2)
    fu, fv = uc - u0, vc - v0
    top = img[v0, u0] * (1 - fu) + img[v0, u0 + 1] * fu
    bottom = img[v0 + 1, u0] * (1 - fu) + img[v0 + 1, u0 + 1] * fu
    return top * (1 - fv) + bottom * fv, ok


def _local_frames(model: CameraModel, corners: F64) -> tuple[F64, F64, F64, F64, Mask]:
    """Per corner: its ray (N, 3), tangent axes ex (image u direction), ey (N, 3), and the local
    view's focal length f (N,) that keeps the lens's pixel area there."""
    h = 0.5
    z, ok0 = model.unproject(corners, in_image=False)
    zu, oku = model.unproject(corners + np.array([h, 0.0]), in_image=False)
    zv, okv = model.unproject(corners + np.array([0.0, h]), in_image=False)
    tu, tv = (zu - z) / h, (zv - z) / h
    ex = tu - np.sum(tu * z, axis=1, keepdims=True) * z
    ex /= np.maximum(np.linalg.norm(ex, axis=1, keepdims=True), 1e-300)
    ey = np.cross(z, ex)
    area = np.abs(np.sum(np.cross(tu, tv) * z, axis=1))  # solid angle per px²
    f = 1.0 / np.sqrt(np.maximum(area, 1e-300))
    return z, ex, ey, f, ok0 & oku & okv & (area > 0)


def _to_local(rays: F64, z: F64, ex: F64, ey: F64, f: F64) -> F64:
    """Local view pixels (N, 2) of rays (N, 3), NaN for rays behind the view."""
    depth = np.sum(rays * z, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ab = (
            f[:, None]
            * np.stack([np.sum(rays * ex, axis=1), np.sum(rays * ey, axis=1)], axis=1)
            / depth[:, None]
        )
    return np.where((depth > 0)[:, None], ab, np.nan)


def _window_radius(
    model: CameraModel, corners: F64, neighbours: NDArray[np.intp], frame: tuple[F64, F64, F64, F64]
) -> F64:
    """Per corner the window radius (local px): a fraction of the distance from the corner to
    the far edges of its four squares, from its neighbours' positions in its local view."""
    rays, ok = model.unproject(np.nan_to_num(corners, nan=0.0), in_image=False)
    ok &= np.isfinite(corners).all(axis=1)
    local = np.full((len(corners), 4, 2), np.nan)
    for k in range(4):
        j = np.maximum(neighbours[:, k], 0)
        has = (neighbours[:, k] >= 0) & ok[j]
        local[has, k] = _to_local(rays[j[has]], *(a[has] for a in frame))
    axes = []
    for plus, minus in ((0, 1), (2, 3)):  # each grid axis from its shorter side
        a, b = local[:, plus], -local[:, minus]
        la, lb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
        use_b = ~np.isfinite(la) | (np.isfinite(lb) & (lb < la))
        axes.append(np.where(use_b[:, None], b, a))
    A, B = axes
    area = np.abs(A[:, 0] * B[:, 1] - A[:, 1] * B[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        # Distance from the corner to the far edge of a square: |A × B| / |B| and |A × B| / |A|.
        reach = area / np.maximum(np.linalg.norm(A, axis=1), np.linalg.norm(B, axis=1))
    return np.where(np.isfinite(reach), _RADIUS_FRACTION * reach, np.nan)


def _symmetry_step(vals: F64, w: F64, ga: F64, gb: F64) -> tuple[F64, F64, F64, Mask]:
    """One Gauss-Newton step for M windows (M, S, S) sampled on the grid (ga, gb) around their
    current centres: the shift (M, 2) that makes them point-symmetric, the weighted contrast
    (M,), the residual asymmetry over contrast (M,) and whether the step is defined (M,)."""
    flip = (slice(None), slice(None, None, -1), slice(None, None, -1))  # x -> -x
    gv, gu = (np.asarray(g_, dtype=np.float64) for g_ in np.gradient(vals, axis=(1, 2)))
    e = vals - vals[flip]
    even = 0.5 * (vals + vals[flip])
    # Shift columns, then a multiplicative illumination gradient k: (k·x)·even.
    cols = np.stack([gu - gu[flip], gv - gv[flip], ga * even, gb * even], axis=-1)
    m = len(vals)
    sw = np.sqrt(w)[..., None]
    A = (cols * sw).reshape(m, -1, 4)
    normal = np.einsum("mpi,mpj->mij", A, A)
    rhs = np.einsum("mpi,mp->mi", A, (e[..., None] * sw).reshape(m, -1))
    scale = 1.0 / np.sqrt(np.maximum(np.einsum("mii->mi", normal), 1e-300))
    normal = normal * scale[:, :, None] * scale[:, None, :]
    ok = np.linalg.cond(normal) < 1e8
    sol = np.zeros((m, 4))
    sol[ok] = np.linalg.solve(normal[ok], (rhs * scale)[ok][..., None])[..., 0]
    sol *= scale
    wsum = np.sum(w, axis=(1, 2))
    mean = np.sum(w * vals, axis=(1, 2)) / wsum
    contrast = np.sqrt(np.sum(w * (vals - mean[:, None, None]) ** 2, axis=(1, 2)) / wsum)
    rest = e - np.einsum("mabi,mi->mab", cols, sol)
    asym = np.sqrt(np.sum(w * rest**2, axis=(1, 2)) / (2 * wsum)) / np.maximum(contrast, 1e-12)
    return -sol[:, :2], contrast, asym, ok


def refine_corners_local(
    image: ImageSource,
    corners: ArrayLike,
    model: CameraModel,
    object_points: ArrayLike,
    *,
    max_radius_px: float = MAX_RADIUS_PX,
    blur_sigma_px: float = BLUR_SIGMA_PX,
) -> CornerRefinement:
    """Refine the chessboard corners (N, 2) of one ``image`` with the lens ``model`` (see the
    module docstring); ``object_points`` (N, 3) give the board grid (which corners neighbour).

    Corners that cannot be refined are NaN in the result, with a reason: window leaving the
    image or the lens's field, squares too small, too little contrast, no convergence, a move
    of more than half the window, or a window that is not point-symmetric.
    """
    img = load_grey(image)
    if (img.shape[1], img.shape[0]) != (model.width, model.height):
        raise CalibrationError(
            f"image is {img.shape[1]}x{img.shape[0]} but the lens model is for {model.width}x{model.height}"
        )
    if blur_sigma_px > 0:
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), blur_sigma_px), dtype=np.float64)
    u0 = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    neighbours = board_neighbours(object_points)
    if len(neighbours) != len(u0):
        raise CalibrationError(f"{len(u0)} corners but {len(neighbours)} object points")
    reasons: dict[int, str] = {}

    def at(indices: NDArray[np.intp]) -> Mask:
        mask = np.zeros(len(u0), bool)
        mask[indices] = True
        return mask

    def drop(mask: Mask, reason: str) -> None:
        for i in np.flatnonzero(mask & alive):
            reasons[int(i)] = reason
        alive[mask] = False

    alive: Mask = np.asarray(np.isfinite(u0).all(axis=1))
    z, ex, ey, f, ok = _local_frames(model, np.where(alive[:, None], u0, 0.0))
    drop(~ok, "outside the lens model's field")
    frame = (z, ex, ey, f)
    radius = np.minimum(
        _window_radius(model, np.where(alive[:, None], u0, np.nan), neighbours, frame), max_radius_px
    )
    drop(np.isnan(radius), "no neighbouring corners to size the refinement window")
    drop(~(radius >= MIN_RADIUS_PX), "squares too small in the image for a refinement window")

    # One sample grid for all corners (the largest window); each corner weights its own part.
    R = int(np.ceil(np.max(radius[alive], initial=MIN_RADIUS_PX))) + 1
    g = np.arange(-R, R + 1, dtype=np.float64)
    gb, ga = np.meshgrid(g, g, indexing="ij")  # (S, S): rows = local b, columns = local a
    r_grid = np.hypot(ga, gb)
    rad = np.where(alive, radius, 1.0)[:, None, None]
    weight = np.exp(-0.5 * (r_grid / (_WEIGHT_SIGMA_FRACTION * rad)) ** 2) * (r_grid <= rad)

    centre = z.copy()
    asym = np.full(len(u0), np.nan)
    converged = np.zeros(len(u0), bool)
    for _ in range(_MAX_ITER):
        idx = np.flatnonzero(alive & ~converged)
        if idx.size == 0:
            break
        c, fl = centre[idx], f[idx]
        bx = ex[idx] - np.sum(ex[idx] * c, axis=1, keepdims=True) * c  # tangent to the new ray
        bx /= np.linalg.norm(bx, axis=1, keepdims=True)
        by = np.cross(c, bx)
        offsets = (
            ga[None, ..., None] * bx[:, None, None] + gb[None, ..., None] * by[:, None, None]
        )  # (M, S, S, 3)
        dirs = c[:, None, None] + offsets / fl[:, None, None, None]
        px, valid = model.project(dirs.reshape(-1, 3), in_image=False)
        vals, inside = _bilinear(img, px[:, 0], px[:, 1])
        shape = (len(idx), 2 * R + 1, 2 * R + 1)
        vals, valid, inside = vals.reshape(shape), valid.reshape(shape), inside.reshape(shape)
        used = weight[idx] > 0
        off_lens = (used & ~valid).any(axis=(1, 2))
        off_image = (used & ~inside).any(axis=(1, 2)) & ~off_lens
        drop(at(idx[off_lens]), "refinement window leaves the lens's field of view")
        drop(at(idx[off_image]), "refinement window leaves the image")
        step, contrast, asym[idx], solved = _symmetry_step(vals, weight[idx], ga, gb)
        drop(at(idx[contrast < _MIN_CONTRAST]), "too little contrast around the corner")
        norm = np.linalg.norm(step, axis=1, keepdims=True)
        step *= np.minimum(1.0, 1.0 / np.maximum(norm, 1e-300))  # capped at 1 px: no overshoot
        new = c + (step[:, :1] * bx + step[:, 1:] * by) / fl[:, None]
        live = alive[idx]
        centre[idx[live]] = (new / np.linalg.norm(new, axis=1, keepdims=True))[live]
        converged[idx[live & solved & (norm[:, 0] < _STEP_TOL)]] = True
    drop(~converged, "refinement did not converge")
    moved = np.linalg.norm(_to_local(centre, z, ex, ey, f), axis=1)
    drop(
        ~(moved <= _MAX_MOVE_FRACTION * radius),
        "refined corner moved more than half its window from the start",
    )
    for i in np.flatnonzero(alive & ~(asym <= _MAX_ASYMMETRY)):
        reasons[int(i)] = f"not a point-symmetric X-junction (asymmetry {asym[i]:.2f})"
        alive[i] = False
    out = np.full((len(u0), 2), np.nan)
    px, ok = model.project(centre[alive], in_image=False)
    out[np.flatnonzero(alive)[ok]] = px[ok]
    drop(at(np.flatnonzero(alive)[~ok]), "outside the lens model's field")
    shift = np.linalg.norm(out - u0, axis=1)
    return CornerRefinement(out, shift, np.where(alive, asym, np.nan), dict(sorted(reasons.items())))


@dataclass(frozen=True)
class RejectedCorner:
    """A detected corner that refinement left out: input view index and name, corner index, why."""

    view: int
    view_name: str
    corner: int
    reason: str


@dataclass(frozen=True)
class RefinementReport:
    """What corner refinement did within one camera's calibration.

    ``rms_before``/``rms_after``: reprojection RMS (px) of the calibration on the detector's
    corners and on the refined ones; ``changes_px``: per round, the largest change of a refined
    corner from the previous round (the first round: from the detection); ``mean_shift_px``:
    mean distance refined − detected; ``n_corners``: refined corners used.
    """

    rms_before: float
    rms_after: float
    rounds: int
    changes_px: tuple[float, ...]
    converged: bool
    mean_shift_px: float
    n_corners: int
    rejected: tuple[RejectedCorner, ...]

    def reasons(self) -> dict[str, int]:
        """How many corners were left out for each reason (asymmetry values stripped)."""
        out: dict[str, int] = {}
        for r in self.rejected:
            key = r.reason.split(" (")[0]
            out[key] = out.get(key, 0) + 1
        return out


def refine_views(
    images: Sequence[ImageSource | None],
    corners: Mapping[int, F64],
    model: CameraModel,
    object_points: Mapping[int, F64],
    view_names: Sequence[str],
    **options: float,
) -> tuple[dict[int, F64], list[RejectedCorner]]:
    """Refine the corners (N_i, 2) of each view i in ``corners`` in ``images[i]`` with ``model``.

    Returns refined corners per view (NaN rows where refinement failed) and the corners left
    out. A view without an image keeps its corners. ``options`` go to :func:`refine_corners_local`.
    """
    refined: dict[int, F64] = {}
    rejected: list[RejectedCorner] = []
    for i, u in corners.items():
        source = images[i]
        if source is None:
            refined[i] = u
            continue
        try:
            res = refine_corners_local(source, u, model, object_points[i], **options)
        except CalibrationFileError:
            raise
        except CalibrationError as err:
            raise CalibrationError(f"{view_names[i]}: {err}") from err
        refined[i] = res.corners
        rejected += [RejectedCorner(i, view_names[i], k, why) for k, why in res.reasons.items()
                     if np.isfinite(u[k]).all()]  # fmt: skip
    return refined, rejected
