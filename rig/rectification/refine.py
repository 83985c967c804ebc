"""Refine a rig's relative rotation (and, where observable, its baseline direction) from the
scene in a recording: ``rig calibrate refine`` (docs/rectification.md).

Up to ``frames`` pairs spread over the recording are matched in the epipolar views of the
calibration to refine (:mod:`rig.rectification.matching`); the matches of all of them feed one
robust estimation (:func:`calibration.relative_pose.refine_relative_pose`), so moving objects
and mismatches, which agree on no single rotation, drop out as outliers. The right camera is
turned (and its centre moved on a sphere about the left one, the baseline's length kept); the
left camera keeps its pose. Before/after vertical disparity is measured on the same inlier
matches in the VPC pair of the given :class:`~rig.rectified.RectifiedPairConfig`.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.errors import CalibrationFailed, CalibrationFileError
from calibration.formats import save_rig
from calibration.formats.rig_yaml import atomic_write_bytes
from calibration.geometry import invert_transform
from calibration.relative_pose import (
    RelativePoseFit,
    RelativePoseOptions,
    refine_relative_pose,
    rig_with_relative_pose,
)
from calibration.rig import Rig
from rig.errors import RecordingError, RectificationError
from rig.recording import PairRecord, Recording
from rig.rectification.matching import MatchOptions, RayMatches, match_pair
from rig.rectification.measure import VerticalDisparity, vertical_disparity
from rig.rectification.views import EpipolarViews
from rig.rectified import RectifiedPairConfig, design_rectified_pair

__all__ = [
    "RectificationRefinement",
    "RefineOptions",
    "backup_path",
    "collect_matches",
    "pick_pairs",
    "refine_frames",
    "refine_recording",
    "refine_rig",
    "save_refined",
]

log = logging.getLogger(__name__)

U8 = NDArray[np.uint8]

# Frames whose grey levels vary less than this are blank (no scene to match).
_BLANK_STD = 2.0

#: ``progress(done, total)`` after each matched pair.
Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class RefineOptions:
    """``frames``: at most this many pairs, evenly spread over the recording; ``view_scale``:
    resolution of the epipolar views (1 = the lenses' own); ``inlier_px``: the consensus
    threshold in view pixels; ``min_matches``: fewest inlier matches to accept a result."""

    frames: int = 20
    view_scale: float = 1.0
    inlier_px: float = 2.0
    min_matches: int = 100
    match: MatchOptions = field(default_factory=MatchOptions)
    pose: RelativePoseOptions = field(default_factory=RelativePoseOptions)


@dataclass(frozen=True)
class RectificationRefinement:
    """What a refinement found: the rig before and after, the fit (correction, uncertainty,
    inliers), the vertical disparity of the inlier matches before and after, and per matched
    pair its number of matches."""

    left: str
    right: str
    rig_before: Rig
    rig_after: Rig
    fit: RelativePoseFit
    before: VerticalDisparity
    after: VerticalDisparity
    matches: int
    matches_per_frame: dict[int, int]
    skipped: dict[int, str] = field(default_factory=dict)


def relative_pose(rig: Rig, left: str, right: str) -> np.ndarray:
    """``T_right_left`` (4, 4) of ``rig``."""
    return invert_transform(rig.T_rig_cam[right]) @ rig.T_rig_cam[left]


def _check_rig(rig: Rig, vpc: RectifiedPairConfig) -> None:
    for name in (vpc.left, vpc.right):
        if name not in rig.cameras:
            raise RectificationError(
                f"the calibration has no camera {name!r} (has {', '.join(rig.names)}); "
                "refinement needs a pair"
            )


def refine_rig(
    rig: Rig,
    matches: RayMatches,
    vpc: RectifiedPairConfig | None = None,
    options: RefineOptions | None = None,
    *,
    views: EpipolarViews | None = None,
) -> RectificationRefinement:
    """Refine ``rig`` from ``matches`` (rays of ``vpc.left`` / ``vpc.right``); RectificationError
    when the matches do not support a result."""
    vpc = vpc or RectifiedPairConfig()
    opts = options or RefineOptions()
    _check_rig(rig, vpc)
    left, right = vpc.left, vpc.right
    views = views or EpipolarViews(rig, left, right, scale=opts.view_scale)
    pose_opts = replace(
        opts.pose,
        inlier_threshold_deg=float(np.degrees(opts.inlier_px / views.px_per_rad)),
        min_inliers=opts.min_matches,
    )
    pair = design_rectified_pair(rig, vpc)
    try:
        fit = refine_relative_pose(
            matches.left, matches.right, relative_pose(rig, left, right), pair.R_cam_rect[left], pose_opts
        )
    except CalibrationFailed as err:
        raise RectificationError(str(err)) from err
    after_rig = rig_with_relative_pose(rig, left, right, fit.T_right_left)
    inl = matches.select(fit.inliers)
    before = vertical_disparity(pair, inl.left, inl.right)
    after = vertical_disparity(design_rectified_pair(after_rig, vpc), inl.left, inl.right)
    counts = np.bincount(matches.frame) if len(matches) else np.zeros(0, dtype=np.int64)
    per_frame = {int(i): int(c) for i, c in enumerate(counts) if c}
    return RectificationRefinement(left, right, rig, after_rig, fit, before, after, len(matches), per_frame)


def _pick(n: int, k: int) -> list[int]:
    """``k`` indices evenly spread over ``range(n)`` (all of them when ``k >= n``)."""
    if k >= n:
        return list(range(n))
    return sorted({round(float(i)) for i in np.linspace(0, n - 1, k)})


def pick_pairs(recording: Recording, frames: int, left: str, right: str) -> list[PairRecord]:
    """Up to ``frames`` pairs evenly spread over ``recording``; RecordingError for a recording
    without both cameras or without pairs."""
    missing = [n for n in ("left", "right") if n not in recording.cameras]
    if missing:
        has = ", ".join(recording.cameras) or "none"
        raise RecordingError(
            f"{recording.root / 'recording.json'}: a recording of camera(s) {has} only; "
            f"refinement needs both {left} and {right}"
        )
    if len(recording) == 0:
        raise RecordingError(f"{recording.root / 'frames.csv'}: no pairs recorded")
    return [recording.pairs[i] for i in _pick(len(recording), frames)]


def collect_matches(
    recording: Recording,
    views: EpipolarViews,
    options: RefineOptions | None = None,
    progress: Progress | None = None,
) -> tuple[RayMatches, dict[int, str]]:
    """Matches of up to ``options.frames`` pairs of ``recording`` (``frame`` = the pair's seq),
    and the pairs skipped with the reason (unreadable frames). RecordingError for a recording
    without both cameras, or whose left and right frames are the same images."""
    opts = options or RefineOptions()
    chosen = pick_pairs(recording, opts.frames, *views.names)
    parts: list[RayMatches] = []
    skipped: dict[int, str] = {}
    identical = 0
    for done, pair in enumerate(chosen, 1):
        try:
            gray_l = recording.read_image(pair, "left", cv2.IMREAD_GRAYSCALE)
            gray_r = recording.read_image(pair, "right", cv2.IMREAD_GRAYSCALE)
            # The same textured image on both sides: one camera recorded twice (two cameras
            # looking at nothing, lens caps on, give blank frames: that is "not enough matches").
            identical += bool(np.array_equal(gray_l, gray_r) and gray_l.std() > _BLANK_STD)
        except RecordingError as err:
            skipped[pair.seq] = str(err)
            log.warning("skipping seq %d: %s", pair.seq, err)
        else:
            parts.append(match_pair(views, gray_l, gray_r, opts.match, frame=pair.seq))
        if progress is not None:
            progress(done, len(chosen))
    read = len(chosen) - len(skipped)
    if read == 0:
        raise RecordingError(f"{recording.root}: none of the {len(chosen)} pairs read could be decoded")
    if identical == read:
        raise RecordingError(
            f"{recording.root}: the left and right frames are the same images: a recording of one camera"
        )
    return RayMatches.concat(parts), skipped


def _enough(matches: RayMatches, opts: RefineOptions, where: str) -> None:
    """RectificationError naming ``where`` (the pairs looked at) when there are too few matches."""
    if len(matches) < opts.min_matches:
        raise RectificationError(
            f"not enough matches: {len(matches)} in {where}, need at least {opts.min_matches} "
            "(a blank or low-texture scene?)"
        )


def refine_frames(
    rig: Rig,
    frames: Sequence[tuple[U8, U8]],
    vpc: RectifiedPairConfig | None = None,
    options: RefineOptions | None = None,
) -> RectificationRefinement:
    """Refine ``rig`` from gray fisheye pairs in memory, each (``vpc.left``'s image,
    ``vpc.right``'s): what :func:`refine_recording` does with a recording's pairs, for frames
    that are not a two-camera recording (a pair of a ring's cameras)."""
    vpc = vpc or RectifiedPairConfig()
    opts = options or RefineOptions()
    _check_rig(rig, vpc)
    views = EpipolarViews(rig, vpc.left, vpc.right, scale=opts.view_scale)
    matches = RayMatches.concat(
        [match_pair(views, a, b, opts.match, frame=i) for i, (a, b) in enumerate(frames)]
    )
    _enough(matches, opts, f"{len(frames)} pairs of {vpc.left}|{vpc.right}")
    return refine_rig(rig, matches, vpc, opts, views=views)


def refine_recording(
    recording: Recording,
    rig: Rig,
    vpc: RectifiedPairConfig | None = None,
    options: RefineOptions | None = None,
    progress: Progress | None = None,
) -> RectificationRefinement:
    """Refine ``rig`` from the scene of ``recording`` (see the module doc)."""
    vpc = vpc or RectifiedPairConfig()
    opts = options or RefineOptions()
    _check_rig(rig, vpc)
    views = EpipolarViews(rig, vpc.left, vpc.right, scale=opts.view_scale)
    matches, skipped = collect_matches(recording, views, opts, progress)
    try:
        _enough(matches, opts, f"{min(len(recording), opts.frames) - len(skipped)} pairs")
        result = refine_rig(rig, matches, vpc, opts, views=views)
    except RectificationError as err:
        raise RectificationError(f"{recording.root}: {err}") from err
    return replace(result, skipped=skipped)


def backup_path(calibration: Path) -> Path:
    """Where the original of a calibration file refined in place is kept: ``rig.orig.yaml`` for
    ``rig.yaml``."""
    return calibration.with_name(f"{calibration.stem}.orig{calibration.suffix}")


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return a.resolve() == b.resolve()


def save_refined(rig: Rig, out: Path, original: Path | None) -> Path | None:
    """Write ``rig`` to ``out`` as rig.yaml, atomically (temp file, fsync, rename). When ``out``
    is the ``original`` calibration file itself, the original's bytes are first kept in
    :func:`backup_path` (once: an existing backup already holds the original and is left as it
    is); returns that backup's path then, else None. CalibrationFileError naming the file that
    cannot be read or written."""
    backup = None
    if original is not None and out.exists() and _same_file(out, original):
        backup = backup_path(original)
        if not backup.exists():
            try:
                data = original.read_bytes()
            except OSError as err:
                raise CalibrationFileError(original, f"cannot read: {err.strerror or err}") from err
            atomic_write_bytes(backup, data)
    save_rig(rig, out)
    return backup
