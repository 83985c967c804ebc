"""Accuracy without ground truth: two stereo pairs that share a camera must agree on the range of
what both see (docs/ring.md).

Pairs P1 = (A, S) and P2 = (S, B) share camera S. P1's valid range pixels are points; moved
into P2's left rectified view (S's centre when S is P2's left camera) each is a pixel and a
range r1 from that view's centre, to compare with P2's own range r2 at that pixel:

    relative disagreement  e = (r1 − r2) / r2

The points move through the shared camera's frame, each pair's design giving its own pose of S
(:func:`camera_pose`): pairs calibrated apart (each refined on its own) are compared where
they meet, in S. P2's range at a pixel is bilinear between the four neighbours where all four
have range, else the nearest pixel's where it has one, else none (no interpolation across a
hole). A point counts where its pixel lies in P2's view (both rectified views show its
direction, left of the matcher's unmatched band: :func:`view_mask`).

The figures of a couple (:class:`ConsistencyFigures`): the share of the points where both pairs
range, the median of |e|, its signed median (a bias), the shares within 3 % and 10 %, and the
disagreement in P2's disparity pixels, ``d1 − d2``: each range's disparity in P2 is its point's
column in P2's left view less its column in P2's right view (exact for either projection).

Coverage of a pair (:func:`range_coverage`): the solid angle of its valid range pixels over the
solid angle of its view (:func:`view_mask`), pixels weighted by
:func:`rig.field.pixel_solid_angles`.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from calibration.geometry import invert_transform, make_transform
from rig.depth import range_points
from rig.errors import EvaluationError
from rig.rectified import RectifiedPair
from rig.ring import PairNames

__all__ = [
    "ConsistencyFigures",
    "Couple",
    "PairRange",
    "TransferredRange",
    "camera_pose",
    "couples",
    "range_coverage",
    "sample_range",
    "transfer_range",
    "view_mask",
]

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
Mask = NDArray[np.bool_]


def view_mask(left_valid: Mask, right_valid: Mask, blind_band_px: int) -> Mask:
    """(H, W) the directions both rectified views show (their lookup tables' masks), the
    matcher's ``blind_band_px`` leftmost (unmatched) columns left out."""
    out: Mask = left_valid & right_valid
    out[:, : max(0, blind_band_px)] = False
    return out


@dataclass(frozen=True)
class PairRange:
    """One pair's range: its design, ``range`` (H, W) float32 m along each left rectified
    pixel's ray (NaN invalid, :attr:`rig.pipeline.DepthFrame.range`) and ``view`` (H, W) bool,
    what it is measured over (:func:`view_mask`)."""

    pair: RectifiedPair
    range: F32
    view: Mask

    def __post_init__(self) -> None:
        shape = (self.pair.camera.height, self.pair.camera.width)
        if self.range.shape != shape or self.view.shape != shape:
            raise EvaluationError(
                f"pair {self.pair.left}|{self.pair.right}: range {self.range.shape} and view "
                f"{self.view.shape} must be the rectified view's {shape}"
            )

    @property
    def names(self) -> PairNames:
        return (self.pair.left, self.pair.right)


def camera_pose(pair: RectifiedPair, name: str) -> F64:
    """T_rig_cam (4, 4) of camera ``name`` as ``pair``'s design has it (its rectified views'
    orientation turned back by ``R_cam_rect``, at their centre)."""
    if name not in pair.R_cam_rect:
        raise EvaluationError(f"camera {name!r} is not in pair {pair.left}|{pair.right}")
    return make_transform(pair.R_rig_rect @ pair.R_cam_rect[name].T, pair.T_rig_rect[name][:3, 3])


def sample_range(range_m: F32, pixels: F64) -> F64:
    """``range_m`` (H, W) at ``pixels`` (N, 2) (u, v): bilinear where the four neighbours all have
    range, else the nearest pixel's where it has one, else NaN (outside the image too)."""
    h, w = range_m.shape
    u, v = pixels[:, 0], pixels[:, 1]
    out = np.full(u.shape, np.nan)
    inside = (u > -0.5) & (u < w - 0.5) & (v > -0.5) & (v < h - 0.5)
    u0 = np.clip(np.floor(u), 0, w - 2).astype(np.intp)
    v0 = np.clip(np.floor(v), 0, h - 2).astype(np.intp)
    fu, fv = np.clip(u - u0, 0.0, 1.0), np.clip(v - v0, 0.0, 1.0)
    r = range_m.astype(np.float64)
    corners = (r[v0, u0], r[v0, u0 + 1], r[v0 + 1, u0], r[v0 + 1, u0 + 1])
    bilinear = (1 - fv) * ((1 - fu) * corners[0] + fu * corners[1]) + fv * (
        (1 - fu) * corners[2] + fu * corners[3]
    )
    four = inside & np.isfinite(bilinear)
    out[four] = bilinear[four]
    un = np.clip(np.rint(u), 0, w - 1).astype(np.intp)
    vn = np.clip(np.rint(v), 0, h - 1).astype(np.intp)
    nearest = inside & ~four
    out[nearest] = r[vn[nearest], un[nearest]]
    return out


@dataclass(frozen=True)
class TransferredRange:
    """Source points that land in the target's view, one entry each: ``pixel`` (N, 2) in the
    target's left rectified view, ``r_source`` (N,) their range from its centre, ``r_target``
    (N,) the target's range there (NaN: none), ``source_index`` (N,) their flat pixel indices
    in the source's image, ``d_source`` / ``d_target`` (N,) each range as a disparity of the
    target pair (px; NaN where the range is)."""

    pixel: F64
    r_source: F64
    r_target: F64
    source_index: NDArray[np.intp]
    d_source: F64
    d_target: F64

    @property
    def both(self) -> Mask:
        """Where both pairs range."""
        return np.isfinite(self.r_target) & np.isfinite(self.d_source) & np.isfinite(self.d_target)

    @property
    def relative(self) -> F64:
        """(r_source − r_target) / r_target (NaN where the target has no range)."""
        out: F64 = (self.r_source - self.r_target) / self.r_target
        return out

    def select(self, keep: Mask) -> TransferredRange:
        return TransferredRange(
            self.pixel[keep], self.r_source[keep], self.r_target[keep], self.source_index[keep],
            self.d_source[keep], self.d_target[keep],
        )  # fmt: skip

    @classmethod
    def concat(cls, parts: Sequence[TransferredRange]) -> TransferredRange:
        if not parts:
            raise EvaluationError("no transferred ranges to join")
        return cls(
            *(np.concatenate([getattr(p, f) for p in parts]) for f in
              ("pixel", "r_source", "r_target", "source_index", "d_source", "d_target"))
        )  # fmt: skip


def _disparity(pair: RectifiedPair, points: F64, columns: F64) -> F64:
    """Disparity (N,) in ``pair`` of points (N, 3) in its left rectified frame whose left
    column is ``columns``: that column less the point's column in the right view (NaN where the
    right view has no pixel for it)."""
    right, ok = pair.camera.project(points - np.array([pair.baseline_m, 0.0, 0.0]), in_image=False)
    return np.where(ok, columns - right[:, 0], np.nan)


def transfer_range(source: PairRange, target: PairRange, shared: str, stride: int = 1) -> TransferredRange:
    """``source``'s valid range pixels (every ``stride``-th row and column) moved through camera
    ``shared`` into ``target``'s left rectified view (see the module doc)."""
    for p in (source, target):
        if shared not in p.names:
            raise EvaluationError(f"camera {shared!r} is not in pair {p.names[0]}|{p.names[1]}")
    src, tgt = source.pair, target.pair
    pts32, index = range_points(source.range, src.camera, None, stride)
    M = (
        invert_transform(tgt.T_rig_rect[tgt.left])
        @ camera_pose(tgt, shared)
        @ invert_transform(camera_pose(src, shared))
        @ src.T_rig_rect[src.left]
    )
    pts = pts32.astype(np.float64) @ M[:3, :3].T + M[:3, 3]
    pixel, ok = tgt.camera.project(pts)
    cols = np.clip(np.rint(pixel[:, 0]), 0, tgt.camera.width - 1).astype(np.intp)
    rows = np.clip(np.rint(pixel[:, 1]), 0, tgt.camera.height - 1).astype(np.intp)
    keep = ok & target.view[rows, cols]
    pixel, pts, index = pixel[keep], pts[keep], index[keep]
    r_source = np.linalg.norm(pts, axis=1)
    r_target = sample_range(target.range, pixel)
    rays, _ = tgt.camera.unproject(pixel, in_image=False)
    return TransferredRange(
        pixel,
        r_source,
        r_target,
        index,
        _disparity(tgt, pts, pixel[:, 0]),
        _disparity(tgt, rays * r_target[:, None], pixel[:, 0]),
    )


@dataclass(frozen=True)
class ConsistencyFigures:
    """What a couple of pairs says about the range (see the module doc): ``points`` of the
    source inside the target's view, ``both`` where both range and ``both_share`` = both /
    points; over those: ``median_abs`` and ``median_signed`` of the relative disagreement,
    ``within_3`` / ``within_10`` the shares with |e| ≤ 3 % / 10 %, ``median_abs_px`` and
    ``median_signed_px`` of the disparity disagreement (NaN when ``both`` is 0)."""

    points: int
    both: int
    both_share: float
    median_abs: float
    median_signed: float
    within_3: float
    within_10: float
    median_abs_px: float
    median_signed_px: float

    @classmethod
    def of(cls, t: TransferredRange) -> ConsistencyFigures:
        both = t.both
        n, k = int(both.size), int(np.count_nonzero(both))
        if k == 0:
            return cls(n, 0, 0.0 if n else float("nan"), *([float("nan")] * 6))
        e = t.relative[both]
        dd = t.d_source[both] - t.d_target[both]
        a = np.abs(e)
        return cls(
            n, k, k / n, float(np.median(a)), float(np.median(e)), float(np.mean(a <= 0.03)),
            float(np.mean(a <= 0.10)), float(np.median(np.abs(dd))), float(np.median(dd)),
        )  # fmt: skip

    def as_dict(self) -> dict[str, float | int]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def figures_by(
    t: TransferredRange, values: F64, edges: Sequence[float]
) -> list[tuple[float, float, ConsistencyFigures]]:
    """:class:`ConsistencyFigures` of the points whose ``values`` (N,) (e.g. ``t.r_target``, a
    field angle) fall in each bin ``[edges[i], edges[i + 1])``."""
    out = []
    for lo, hi in itertools.pairwise(edges):
        out.append((float(lo), float(hi), ConsistencyFigures.of(t.select((values >= lo) & (values < hi)))))
    return out


def range_coverage(pr: PairRange, solid_angles: F64) -> float:
    """The solid angle of ``pr``'s valid range pixels over that of its view (see the module
    doc); ``solid_angles`` (H, W) of its rectified view (:func:`rig.field.pixel_solid_angles`)."""
    view_sr = float(solid_angles[pr.view].sum())
    if view_sr <= 0.0:
        raise EvaluationError(f"pair {pr.names[0]}|{pr.names[1]}: its view is empty")
    return float(solid_angles[pr.view & np.isfinite(pr.range)].sum()) / view_sr


@dataclass(frozen=True)
class Couple:
    """Two pairs sharing camera ``shared``: ``source``'s range is measured in ``target``'s view."""

    source: PairNames
    target: PairNames
    shared: str

    @property
    def label(self) -> str:
        return f"{'|'.join(self.source)} → {'|'.join(self.target)}"


def couples(pairs: Sequence[PairNames]) -> list[Couple]:
    """Every two of ``pairs`` that share one camera. The target is the pair whose left camera is
    the shared one (its range is from that camera's centre); where both or neither have it on
    the left, the later pair in ``pairs`` is the target. Pairs of the same two cameras are not a
    couple."""
    out = []
    for i, p in enumerate(pairs):
        for q in pairs[i + 1 :]:
            shared = set(p) & set(q)
            if len(shared) != 1:
                continue
            s = shared.pop()
            source, target = (q, p) if p[0] == s and q[0] != s else (p, q)
            out.append(Couple(tuple(source), tuple(target), s))  # type: ignore[arg-type]
    return out
