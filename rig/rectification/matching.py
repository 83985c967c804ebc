"""Sparse matches between the two cameras of a pair, as rays (docs/rectification.md).

Per pair: SIFT keypoints in both epipolar lat-lon views (:class:`~rig.rectification.views.
EpipolarViews`, where both cameras see), nearest-neighbour matching of the descriptors with
Lowe's ratio test and a mutual check, then each match's right position refined to sub-pixel
precision by Lucas-Kanade on the views (the two views sample the same rays, so patches align
up to parallax). Matches come out as unit rays in each camera's frame, through the camera
models, ready for :func:`calibration.relative_pose.refine_relative_pose`.

Matching is guided by the calibration the views were made with: a right keypoint is a candidate
for a left one only within ``max_row_gap_deg`` of its row (its epipolar plane) and with a
disparity between ``-max_row_gap_deg`` and ``max_disparity_deg``. Repeated texture (bricks,
tiles) then offers far fewer look-alikes, so the ratio test keeps more true matches; a
calibration off by more than the gap finds few matches, which reads "not enough matches", not
a verdict.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from rig.errors import ConfigError
from rig.rectification.views import EpipolarViews
from rig.subpixel import normalise_contrast

__all__ = ["MatchOptions", "RayMatches", "match_pair"]

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]


@dataclass(frozen=True)
class MatchOptions:
    """``max_features`` per view (strongest first); ``ratio``: Lowe's ratio test;
    ``lk_window`` (px, odd; 0 = keep the keypoints' positions): the Lucas-Kanade patch;
    ``lk_max_shift_px``: a refinement moving a match further is dropped (it found something else);
    ``max_row_gap_deg`` / ``max_disparity_deg``: the guided search (see the module doc; None:
    every right keypoint is a candidate)."""

    max_features: int = 4000
    ratio: float = 0.9
    lk_window: int = 15
    lk_max_shift_px: float = 1.5
    max_row_gap_deg: float | None = 4.0
    max_disparity_deg: float = 25.0

    def __post_init__(self) -> None:
        if self.max_features < 8:
            raise ConfigError(f"matching: max_features must be >= 8, got {self.max_features}")
        if not 0.0 < self.ratio <= 1.0:
            raise ConfigError(f"matching: ratio must be in (0, 1], got {self.ratio}")
        if self.lk_window and (self.lk_window < 5 or self.lk_window % 2 == 0):
            raise ConfigError(f"matching: lk_window must be 0 or an odd number >= 5, got {self.lk_window}")
        if self.max_row_gap_deg is not None and not 0.0 < self.max_row_gap_deg <= 45.0:
            raise ConfigError(
                f"matching: max_row_gap_deg must be in (0, 45] or None, got {self.max_row_gap_deg}"
            )


@dataclass(frozen=True)
class RayMatches:
    """``left`` / ``right`` (N, 3) unit rays in each camera's frame; ``frame`` (N,) the index of
    the pair each match came from."""

    left: F64
    right: F64
    frame: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.left.shape[0])

    @classmethod
    def empty(cls) -> RayMatches:
        return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64))

    @classmethod
    def concat(cls, parts: Sequence[RayMatches]) -> RayMatches:
        if not parts:
            return cls.empty()
        return cls(
            np.concatenate([p.left for p in parts]),
            np.concatenate([p.right for p in parts]),
            np.concatenate([p.frame for p in parts]),
        )

    def select(self, keep: NDArray[np.bool_]) -> RayMatches:
        return RayMatches(self.left[keep], self.right[keep], self.frame[keep])


def _candidates(pl: F64, pr: F64, px_per_deg: float, options: MatchOptions) -> NDArray[np.uint8] | None:
    """Mask (n_left, n_right) of the pairs the guided search allows (None: all of them)."""
    if options.max_row_gap_deg is None:
        return None
    gap = options.max_row_gap_deg * px_per_deg
    rows = np.abs(pl[:, None, 1] - pr[None, :, 1]) <= gap
    disparity = pl[:, None, 0] - pr[None, :, 0]
    allowed = rows & (disparity >= -gap) & (disparity <= options.max_disparity_deg * px_per_deg)
    return np.ascontiguousarray(allowed, dtype=np.uint8)


def _mutual_ratio_matches(
    desc_l: NDArray[Any] | None, desc_r: NDArray[Any] | None, ratio: float, allowed: NDArray[np.uint8] | None
) -> list[tuple[int, int]]:
    """(left index, right index) pairs among the ``allowed`` ones passing the ratio test (a lone
    candidate passes) whose right keypoint's own best match is the same left keypoint."""
    if desc_l is None or desc_r is None or desc_l.ndim != 2 or desc_r.ndim != 2:
        return []
    if len(desc_l) < 2 or len(desc_r) < 2:
        return []
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    if allowed is None:
        forward = matcher.knnMatch(desc_l, desc_r, k=2)
        backward_raw = matcher.knnMatch(desc_r, desc_l, k=1)
    else:
        forward = matcher.knnMatch(desc_l, desc_r, k=2, mask=allowed)
        backward_raw = matcher.knnMatch(desc_r, desc_l, k=1, mask=np.ascontiguousarray(allowed.T))
    backward = {m[0].queryIdx: m[0].trainIdx for m in backward_raw if m}
    out = []
    for m in forward:
        if not m or (len(m) == 2 and m[0].distance >= ratio * m[1].distance):
            continue
        if backward.get(m[0].trainIdx) == m[0].queryIdx:
            out.append((m[0].queryIdx, m[0].trainIdx))
    return out


# Normalised views for Lucas-Kanade: z-scores in [-4, 4] as 8-bit (what OpenCV's LK takes).
_Z_GAIN = 32.0


def _normalised_u8(view: U8) -> U8:
    """Local contrast normalisation (:func:`rig.subpixel.normalise_contrast`) as uint8: the two
    cameras see a point at different angles off their axes, so vignetting gives it different
    brightness and a brightness ramp, which would bias Lucas-Kanade's step."""
    z = normalise_contrast(view)
    return np.asarray(np.clip(z * _Z_GAIN + 128.0, 0, 255), dtype=np.uint8)


def _lk_refine(
    view_l: U8, view_r: U8, pl: NDArray[np.float32], pr: NDArray[np.float32], options: MatchOptions
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Right positions refined by Lucas-Kanade from the left patches; which succeeded."""
    win = (options.lk_window, options.lk_window)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.001)
    refined, status, _ = cv2.calcOpticalFlowPyrLK(
        _normalised_u8(view_l), _normalised_u8(view_r), pl.reshape(-1, 1, 2), pr.reshape(-1, 1, 2).copy(),
        winSize=win, maxLevel=0, criteria=criteria, flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )  # fmt: skip
    refined = np.asarray(refined, dtype=np.float32).reshape(-1, 2)
    ok = (status.ravel() == 1) & np.isfinite(refined).all(axis=1)
    ok &= np.linalg.norm(refined - pr, axis=1) <= options.lk_max_shift_px
    return refined, ok


def match_pair(
    views: EpipolarViews, left_gray: U8, right_gray: U8, options: MatchOptions | None = None, frame: int = 0
) -> RayMatches:
    """Matches between one gray fisheye pair (each (H, W) uint8 of its camera's size) as rays."""
    opts = options or MatchOptions()
    left, right = views.names
    view_l, view_r = views.remap(left, left_gray), views.remap(right, right_gray)
    sift = cv2.SIFT.create(nfeatures=opts.max_features)
    kp_l, desc_l = sift.detectAndCompute(view_l, views.mask)
    kp_r, desc_r = sift.detectAndCompute(view_r, views.mask)
    if len(kp_l) < 2 or len(kp_r) < 2:
        return RayMatches.empty()
    all_l = np.array([k.pt for k in kp_l], dtype=np.float64)
    all_r = np.array([k.pt for k in kp_r], dtype=np.float64)
    allowed = _candidates(all_l, all_r, views.px_per_rad * np.pi / 180.0, opts)
    pairs = _mutual_ratio_matches(np.asarray(desc_l), np.asarray(desc_r), opts.ratio, allowed)
    if not pairs:
        return RayMatches.empty()
    pl = all_l[[i for i, _ in pairs]].astype(np.float32)
    pr = all_r[[j for _, j in pairs]].astype(np.float32)
    if opts.lk_window:
        pr, ok = _lk_refine(view_l, view_r, pl, pr, opts)
        pl, pr = pl[ok], pr[ok]
    n = pl.shape[0]
    return RayMatches(
        views.rays(left, pl.astype(np.float64)),
        views.rays(right, pr.astype(np.float64)),
        np.full(n, frame, dtype=np.int64),
    )
