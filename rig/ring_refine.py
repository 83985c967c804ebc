"""Refining a whole rig from its scene, and applying only what makes it better (docs/ring.md,
"Refining a ring").

Every pair's features are matched in its epipolar views (:mod:`rig.rectification.matching`), and
one rotation correction per camera (the first camera holds the rig frame) is fitted to all of
them at once: each match's two rays must lie in one plane through the pair's baseline (their
vertical disparity, in pixels of the lens's own resolution, robust to mismatches). The cameras
of a ring belong to two pairs each, so a correction is one camera's for both of its pairs, where
refining pair by pair would turn the same camera two ways. Translations are kept: the baselines
hold the scale.

The result is measured, never trusted: the vertical disparity of every pair, and with three
cameras or more the agreement of every couple of pairs sharing a camera
(:mod:`rig.evaluate.consistency`: what range needs, which vertical disparity does not observe),
before and after, on the same frames. The corrected rig is applied only when no pair's vertical
disparity and no couple's disagreement gets worse (each within ``tolerance``); otherwise
:attr:`RingRefinement.applied` is False and :attr:`RingRefinement.reason` names what got worse.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from calibration.rig import Rig
from rig.errors import RectificationError
from rig.evaluate.consistency_study import consistency_study
from rig.rectification.matching import MatchOptions, RayMatches, match_pair
from rig.rectification.measure import VerticalDisparity, vertical_disparity
from rig.rectification.views import EpipolarViews, angular_resolution
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from rig.ring import PairNames, adjacent_pairs
from rig.stereo import StereoParams

__all__ = ["RingRefineOptions", "RingRefinement", "refine_ring"]

U8 = NDArray[np.uint8]
F64 = NDArray[np.float64]
#: ``progress(step, total)`` after each stage of the work.
Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class RingRefineOptions:
    """``view_px_per_deg``: the epipolar views' resolution; ``max_features`` per view;
    ``min_matches`` per pair; ``prior_deg``: the scale of the corrections' prior (a weak pull
    towards none); ``tolerance``: how much worse a pair's vertical disparity p50 (px) or a
    couple's median disagreement (fraction) may get and still count as no worse;
    ``cache_dir``: the LUT cache; ``stereo``: the stereo parameters the couples' agreement is
    measured with, the ones the depth will be served with (None: the defaults)."""

    view_px_per_deg: float = 5.0
    max_features: int = 8000
    min_matches: int = 100
    prior_deg: float = 1.0
    tolerance_px: float = 0.02
    tolerance: float = 0.002
    cache_dir: str | Path | None = None
    stereo: StereoParams | None = None


@dataclass(frozen=True)
class RingRefinement:
    """What :func:`refine_ring` did: the rig before and after (``rig`` is the one to use: the
    corrected one only when ``applied``), each camera's correction (degrees, about its own axes),
    every pair's vertical disparity and, with three cameras or more, every couple's median
    disagreement before and after."""

    rig_before: Rig
    rig_after: Rig
    applied: bool
    reason: str | None
    corrections_deg: dict[str, F64]
    vertical_before: dict[PairNames, VerticalDisparity]
    vertical_after: dict[PairNames, VerticalDisparity]
    agreement_before: dict[str, float] = field(default_factory=dict)
    agreement_after: dict[str, float] = field(default_factory=dict)
    coverage_before: dict[PairNames, float] = field(default_factory=dict)
    coverage_after: dict[PairNames, float] = field(default_factory=dict)

    @property
    def rig(self) -> Rig:
        return self.rig_after if self.applied else self.rig_before


def _matches(
    rig: Rig, pairs: Sequence[PairNames], frames: Sequence[Mapping[str, U8]], opts: RingRefineOptions
) -> dict[PairNames, RayMatches]:
    out = {}
    for a, b in pairs:
        views = EpipolarViews(rig, a, b, max_px_per_deg=opts.view_px_per_deg, cache_dir=opts.cache_dir)
        found = RayMatches.concat(
            [
                match_pair(views, f[a], f[b], MatchOptions(max_features=opts.max_features), frame=i)
                for i, f in enumerate(frames)
            ]
        )
        if len(found) < opts.min_matches:
            raise RectificationError(
                f"pair {a}|{b}: {len(found)} matches in {len(frames)} frames, need {opts.min_matches} "
                "(a blank or low-texture scene?)"
            )
        out[(a, b)] = found
    return out


def _corrected(rig: Rig, rotvecs: F64) -> Rig:
    """``rig`` with camera k turned by ``rotvecs[k]`` (about its own axes)."""
    T = {}
    for k, name in enumerate(rig.names):
        Tk = rig.T_rig_cam[name].copy()
        Tk[:3, :3] = Tk[:3, :3] @ Rotation.from_rotvec(rotvecs[k]).as_matrix()
        T[name] = Tk
    return Rig(dict(rig.cameras), T)


def _out_of_plane(rig: Rig, a: str, b: str, m: RayMatches, f_px: float) -> F64:
    """Each match's rays' elevations about the baseline, their difference in pixels."""
    x = rig.center(b) - rig.center(a)
    x /= np.linalg.norm(x)
    up = np.cross(x, [0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.cross(x, [1.0, 0.0, 0.0])
    y = up / np.linalg.norm(up)
    z = np.cross(x, y)
    ra = m.left @ rig.T_rig_cam[a][:3, :3].T
    rb = m.right @ rig.T_rig_cam[b][:3, :3].T
    ea, eb = np.arctan2(ra @ y, ra @ z), np.arctan2(rb @ y, rb @ z)
    out: F64 = f_px * np.angle(np.exp(1j * (ea - eb)))
    return out


def _fit(rig: Rig, matches: Mapping[PairNames, RayMatches], opts: RingRefineOptions) -> F64:
    """One rotation vector per camera (the first fixed) bringing every match into its plane."""
    n = len(rig.names)
    f_px = {name: angular_resolution(rig.cameras[name]) for name in rig.names}
    prior = math.radians(opts.prior_deg)

    def residuals(x: F64) -> F64:
        rot = np.vstack([np.zeros(3), x.reshape(n - 1, 3)])
        corrected = _corrected(rig, rot)
        parts = [_out_of_plane(corrected, a, b, m, f_px[a]) for (a, b), m in matches.items()]
        return np.concatenate([*parts, x / prior])

    solution = least_squares(residuals, np.zeros(3 * (n - 1)), loss="soft_l1", f_scale=1.0, x_scale="jac")
    rot: F64 = np.vstack([np.zeros(3), solution.x.reshape(n - 1, 3)])
    return rot


def _vertical(rig: Rig, matches: Mapping[PairNames, RayMatches]) -> dict[PairNames, VerticalDisparity]:
    return {
        (a, b): vertical_disparity(
            design_rectified_pair(rig, RectifiedPairConfig(left=a, right=b)), m.left, m.right
        )
        for (a, b), m in matches.items()
    }


def _px(v: VerticalDisparity) -> str:
    return "none" if v.p50_px is None else f"{v.p50_px:.2f}"


def _worse(before: float | None, after: float | None, tolerance: float) -> bool:
    return before is not None and (after is None or after > before + tolerance)


def refine_ring(
    rig: Rig,
    frames: Sequence[Mapping[str, U8]],
    pairs: Sequence[PairNames] | None = None,
    options: RingRefineOptions | None = None,
    progress: Progress | None = None,
) -> RingRefinement:
    """Refine ``rig``'s camera rotations from ``frames`` (each an image per camera) and measure
    the result (see the module doc). RectificationError when a pair has too few matches."""
    opts = options or RingRefineOptions()
    chosen = adjacent_pairs(rig, pairs)
    total = 4 if len(chosen) > 1 else 2

    def step(k: int) -> None:
        if progress is not None:
            progress(k, total)

    matches = _matches(rig, chosen, frames, opts)
    step(1)
    rot = _fit(rig, matches, opts)
    after = _corrected(rig, rot)
    v_before, v_after = _vertical(rig, matches), _vertical(after, matches)
    step(2)
    worse = [
        f"pair {a}|{b}'s vertical disparity {_px(v_before[(a, b)])} -> {_px(v_after[(a, b)])} px"
        for (a, b) in chosen
        if _worse(v_before[(a, b)].p50_px, v_after[(a, b)].p50_px, opts.tolerance_px)
    ]
    agree_b: dict[str, float] = {}
    agree_a: dict[str, float] = {}
    cov_b: dict[PairNames, float] = {}
    cov_a: dict[PairNames, float] = {}
    if len(chosen) > 1:
        studies = []
        for k, r in enumerate((rig, after)):
            studies.append(consistency_study(r, frames, chosen, stereo=opts.stereo, cache_dir=opts.cache_dir))
            step(3 + k)
        for study, agree, cov in zip(studies, (agree_b, agree_a), (cov_b, cov_a), strict=True):
            agree.update({c.couple.label: c.figures.median_abs for c in study.couples})
            cov.update({p.names: float(np.mean(p.coverage)) for p in study.pairs})
        worse += [
            f"couple {label}'s median disagreement {100 * agree_b[label]:.2f} -> {100 * agree_a[label]:.2f} %"
            for label in agree_b
            if _worse(agree_b[label], agree_a.get(label), opts.tolerance)
        ]
    return RingRefinement(
        rig_before=rig,
        rig_after=after,
        applied=not worse,
        reason=None if not worse else "not applied, it makes things worse: " + "; ".join(worse),
        corrections_deg={name: np.degrees(rot[k]) for k, name in enumerate(rig.names)},
        vertical_before=v_before,
        vertical_after=v_after,
        agreement_before=agree_b,
        agreement_after=agree_a,
        coverage_before=cov_b,
        coverage_after=cov_a,
    )
