"""Is depth still coming? The share of the pair's overlap with depth, watched frame by frame.

A matcher whose settings broke it, a camera swapped or replaced mid-stream, a lens covered: none
of them fails, each makes the valid depth collapse while every frame is still processed. The
watch keeps the **coverage** of each published frame (the share of the directions both rectified
views show, the matcher's unmatched band left out, that have depth), and compares the median of
the last ``recent_s`` with the median of the ``reference_s`` before them. When the recent median
falls below ``collapse_ratio`` of the reference, :meth:`DepthWatch.verdict` says so, with the
figures and, when the stereo parameters changed in between, which change: the service reports it
as ``degraded`` (service.runtime) and looks for the likely cause (rig.calibration_check on the
newest pair: cameras swapped, rows apart). The verdict holds for as long as the collapse lasts
(until the recent median is back to ``recover_ratio`` of the coverage before it), even where
that is for good: a blank wall in front of the rig is reported as much as a swapped camera, with
the check's findings telling them apart. A scene that holds little texture from the start never
collapses: there is no coverage to fall from.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from rig.in_effect import PairInEffect
from rig.match_input import matcher_views
from rig.stereo import StereoMatcher, StereoParams

__all__ = ["Coverage", "DepthWatch", "SettingsTrial", "overlap_mask", "try_settings"]


def overlap_mask(in_effect: PairInEffect) -> NDArray[np.bool_]:
    """(H, W) the directions both rectified views show, without the matcher's unmatched band
    (its first ``min_disparity + disparity_range`` columns): where depth can be."""
    luts = in_effect.geometry.luts
    left, right = in_effect.names
    mask = luts[left].valid & luts[right].valid
    band = min(in_effect.stereo.blind_band_px, mask.shape[1])
    mask = mask.copy()
    mask[:, :band] = False
    return mask


@dataclass(frozen=True)
class Coverage:
    """One frame's share of the overlap with depth, when it was published and under which
    revision of the pair in effect."""

    at_s: float
    share: float
    revision: int


class DepthWatch:
    """Coverage per frame and the verdict on its collapse (see the module doc). Thread-safe:
    :meth:`observe` from the worker, :meth:`verdict` from anywhere."""

    def __init__(
        self,
        *,
        recent_s: float = 10.0,
        reference_s: float = 60.0,
        collapse_ratio: float = 0.35,
        min_reference: float = 0.10,
        min_frames: int = 5,
        recover_ratio: float = 0.7,
    ) -> None:
        self.recent_s, self.reference_s = recent_s, reference_s
        self.collapse_ratio, self.min_reference, self.min_frames = collapse_ratio, min_reference, min_frames
        self.recover_ratio = recover_ratio
        self._lock = threading.Lock()
        self._latched: tuple[float, str] | None = None  # the reference before a collapse, and its text
        self._history: deque[Coverage] = deque()
        self._mask: tuple[object, int, NDArray[np.bool_]] | None = None

    def coverage(self, valid: NDArray[np.bool_], in_effect: PairInEffect) -> float:
        """The share of ``in_effect``'s overlap (:func:`overlap_mask`) that ``valid`` covers."""
        band = in_effect.stereo.blind_band_px
        held = self._mask
        # The geometry by identity (a correction brings a new one), the band by value.
        if (
            held is None
            or held[0] is not in_effect.geometry
            or held[1] != band
            or held[2].shape != valid.shape
        ):
            held = (in_effect.geometry, band, overlap_mask(in_effect))
            self._mask = held
        mask = held[2]
        total = int(np.count_nonzero(mask))
        return float(np.count_nonzero(valid & mask)) / total if total else 0.0

    def observe(self, at_s: float, share: float, revision: int) -> None:
        with self._lock:
            self._history.append(Coverage(at_s, share, revision))
            horizon = at_s - self.recent_s - self.reference_s
            while self._history and self._history[0].at_s < horizon:
                self._history.popleft()

    def latest(self) -> Coverage | None:
        with self._lock:
            return self._history[-1] if self._history else None

    def verdict(self, now_s: float) -> str | None:
        """Why the depth collapsed, or None while it has not (or too little is known). A collapse
        holds, against the coverage from before it, until the recent median is back to
        ``recover_ratio`` of that."""
        with self._lock:
            history = list(self._history)
            latched = self._latched
        recent = [c for c in history if c.at_s >= now_s - self.recent_s]
        if len(recent) < self.min_frames:
            return latched[1] if latched is not None else None
        now = float(np.median([c.share for c in recent]))
        if latched is not None:
            if now >= self.recover_ratio * latched[0]:
                with self._lock:
                    self._latched = None
                return None
            return latched[1]
        start = now_s - self.recent_s - self.reference_s
        before = [c for c in history if start <= c.at_s < now_s - self.recent_s]
        if len(before) < self.min_frames:
            return None
        then = float(np.median([c.share for c in before]))
        if then < self.min_reference or now >= self.collapse_ratio * then:
            return None
        text = f"valid depth fell from {100 * then:.0f} % to {100 * now:.0f} % of the pair's overlap"
        changed = [c.revision for c in (*before, *recent) if c.revision != before[0].revision]
        if changed:
            text += f", since the configuration changed to revision {changed[0]}"
        with self._lock:
            self._latched = (then, text)
        return text


@dataclass(frozen=True)
class SettingsTrial:
    """New stereo parameters tried against the ones in effect on one rectified pair: the share of
    the overlap each gives depth on (the matcher's own output, before post-processing), and the
    share of the pixels both match where they agree within a pixel."""

    current_share: float
    new_share: float
    agreement: float

    def collapse(self, ratio: float = 0.5) -> str | None:
        """Why the new parameters break the matcher on this pair, or None: they give depth on
        less than ``ratio`` of what the current ones do, or disagree with them on more than half
        of the pixels both match. None when the current ones give almost nothing to compare."""
        if self.current_share < 0.05:
            return None
        if self.new_share < ratio * self.current_share or self.agreement < 0.5:
            return (
                f"on the newest frame they give depth on {100 * self.new_share:.0f} % of the overlap "
                f"(the parameters in effect: {100 * self.current_share:.0f} %) and agree with the "
                f"parameters in effect on {100 * self.agreement:.0f} % of the pixels both match"
            )
        return None


def _gray(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    return image if image.ndim == 2 else np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), np.uint8)


def try_settings(
    in_effect: PairInEffect, left: NDArray[np.uint8], right: NDArray[np.uint8], params: StereoParams
) -> SettingsTrial:
    """Match the rectified pair ``left``, ``right`` (gray or BGR, the pair in effect's size) with
    the parameters in effect and with ``params`` (fresh matchers: the pipeline's are busy) and
    compare them over the overlap (:func:`overlap_mask` with the wider unmatched band)."""
    left, right = _gray(left), _gray(right)
    seen = in_effect.geometry.seen
    results = []
    for p in (in_effect.stereo, params):
        # Each set of parameters on the input the pipeline would give its matcher.
        views = matcher_views(p, left, right)
        matcher = StereoMatcher(p)
        raw = matcher.compute(views.left, views.right, seen, unnormalised=views.unnormalised)
        results.append(matcher.disparity_of(raw))
    current, new = results
    mask = overlap_mask(in_effect)
    mask[:, : min(params.blind_band_px, mask.shape[1])] = False
    total = max(1, int(np.count_nonzero(mask)))
    both = current.valid & new.valid & mask
    close = np.abs(current.disparity[both] - new.disparity[both]) <= 1.0
    return SettingsTrial(
        float(np.count_nonzero(current.valid & mask)) / total,
        float(np.count_nonzero(new.valid & mask)) / total,
        float(close.mean()) if close.size else 0.0,
    )
