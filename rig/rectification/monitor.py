"""The live rectification measure and the opt-in online refinement (docs/rectification.md).

Every ``check_interval_s`` a low-priority thread takes the newest pair the service has (never a
frame of its own, never on the depth worker's path), matches it in the epipolar views
(:mod:`rig.rectification.matching`), keeps the matches that agree on one relative pose (the
robust fit of :func:`calibration.relative_pose.refine_relative_pose`, so moving objects and
mismatches do not count) and measures their vertical disparity in the rectified pair in effect. The status
says ``degraded`` when the last ``confirm_checks`` measurements all pass a bound; a check
without enough matches (or with matches bunched in one place) says ``not enough matches``,
never ``degraded``.

Online refinement (``auto_refine``) pools the consistent matches of the checks since the last
correction and applies the pooled rotation correction only when every condition holds: enough
pooled matches, a correction at least three standard deviations from zero, the last
``stable_checks`` single-check estimates within ``stable_deg`` of it, a step no larger than
``max_step_deg`` and a vertical disparity at least ``min_gain_px`` smaller on the pooled
matches. The baseline direction is never changed online (``rig calibrate refine`` does that).
Applying calls ``apply(new_rig)`` (the service rebuilds its lookup tables there and swaps them
in) on this thread, logs once and starts a new pool.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from calibration.errors import CalibrationError, CalibrationFailed
from calibration.geometry import rotation_angle
from calibration.relative_pose import (
    RelativePoseFit,
    RelativePoseOptions,
    refine_relative_pose,
    rig_with_relative_pose,
)
from calibration.rig import Rig
from rig.counters import CounterValue, complete
from rig.errors import RigError
from rig.in_effect import PairInEffect
from rig.rectification.matching import MatchOptions, RayMatches, match_pair
from rig.rectification.measure import VerticalDisparity, vertical_disparity
from rig.rectification.refine import relative_pose, save_refined
from rig.rectification.status import (
    CheckResult,
    RectificationConfig,
    RectificationState,
    RectificationStatus,
    p50_trend,
    rectification_state,
)
from rig.rectification.views import EpipolarViews
from rig.rectified import RectifiedPair

__all__ = [
    "AppliedCorrection",
    "CheckResult",
    "RectificationConfig",
    "RectificationMonitor",
    "RectificationState",
    "RectificationStatus",
    "drift_deg",
]

log = logging.getLogger("rig.rectification")

U8 = NDArray[np.uint8]
F64 = NDArray[np.float64]

#: The newest gray pair (left, right), or None while there is none.
PairSource = Callable[[], tuple[U8, U8] | None]
# The monitor's thread runs at this nice value (the lowest priority; raising nice needs no rights).
_MONITOR_NICE = 19
# Consensus threshold of a check, in epipolar-view pixels.
_INLIER_PX = 2.0


@dataclass
class _Pool:
    """Consistent matches and single-check estimates since the last applied correction."""

    matches: deque[RayMatches]
    estimates: deque[F64]

    @classmethod
    def new(cls, size: int) -> _Pool:
        return cls(deque(maxlen=size), deque(maxlen=size))


@dataclass(frozen=True)
class AppliedCorrection:
    """An online correction applied: when (``time.monotonic()`` s), its angle, and the pair's
    total drift from its calibration after it (degrees)."""

    at_s: float
    angle_deg: float
    total_deg: float


def drift_deg(calibrated: Rig, rig: Rig, left: str, right: str) -> float:
    """The angle between the relative rotations of ``left`` and ``right`` in two calibrations."""
    R_cal = relative_pose(calibrated, left, right)[:3, :3]
    R_now = relative_pose(rig, left, right)[:3, :3]
    return math.degrees(rotation_angle(R_now @ R_cal.T))


@dataclass
class _Counters:
    checks: int = 0
    without_matches: int = 0
    corrections: int = 0
    last_correction_deg: float | None = None
    refinement: str | None = None
    history: deque[CheckResult] = field(default_factory=lambda: deque(maxlen=1024))


class RectificationMonitor:
    """Measures (and optionally refines) the rectification of the pair in effect that
    ``in_effect`` returns (a :class:`rig.pipeline.DepthPipeline`'s) from the pairs ``source``
    gives (see the module doc). Its epipolar views are rebuilt, at the monitor's resolution,
    whenever the pair in effect gets another calibration. :meth:`check` runs one check on the
    calling thread; :meth:`start` runs them every ``check_interval_s`` on a thread of its own.
    ``apply(rig)`` makes a correction take effect (the service: ``DepthPipeline.apply``)."""

    def __init__(
        self,
        in_effect: Callable[[], PairInEffect],
        source: PairSource,
        options: RectificationConfig | None = None,
        apply: Callable[[Rig], None] | None = None,
        calibration_path: Path | None = None,
        cache_dir: str | Path | None = None,
    ) -> None:
        self.options = options or RectificationConfig()
        self.calibration_path = calibration_path
        self._in_effect = in_effect
        self._source = source
        self._apply = apply
        self._cache_dir = cache_dir
        self._lock = threading.Lock()
        self._counters = _Counters()
        self._pool = _Pool.new(self.options.pool_checks)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        # Built by the first check (not at start-up), for the calibration it was built from.
        self._views: tuple[Rig, EpipolarViews] | None = None
        # The calibration the service started with: online corrections add up to at most
        # max_total_deg from it (one step of that size is refused; so are four smaller ones).
        self._calibrated = in_effect().geometry.rig
        self._recalibrate: str | None = None
        self.corrections: list[AppliedCorrection] = []

    # ----- geometry ----------------------------------------------------------------------------
    def _geometry(self) -> tuple[Rig, EpipolarViews, RectifiedPair]:
        """The pair in effect's calibration and design, and epipolar views of that calibration."""
        now = self._in_effect()
        rig, pair = now.geometry.rig, now.pair
        with self._lock:
            views = self._views
        if views is None or views[0] is not rig:
            built = EpipolarViews(
                rig,
                pair.left,
                pair.right,
                max_px_per_deg=self.options.view_px_per_deg,
                cache_dir=self._cache_dir,
            )
            views = (rig, built)
            with self._lock:
                self._views = views
        return rig, views[1], pair

    @property
    def pair(self) -> RectifiedPair:
        return self._in_effect().pair

    # ----- lifecycle ---------------------------------------------------------------------------
    def start(self) -> None:
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="rig-rectification", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 10.0) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)
        self._thread = None

    def _run(self) -> None:
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), _MONITOR_NICE)
        except (OSError, AttributeError):  # no per-thread priority here: runs at normal priority
            log.debug("rectification monitor: could not lower its thread's priority")
        while not self._stop.wait(self.options.check_interval_s):
            pair = self._source()
            if pair is None:
                continue
            try:
                self.check(*pair)
            except RigError as err:  # a frame of the wrong size, say: reported, never fatal
                log.warning("rectification check failed: %s", err)
            except Exception:  # a bug must not end the measurement for good
                log.exception("rectification check: unexpected error")

    # ----- one check ---------------------------------------------------------------------------
    def check(self, left: U8, right: U8) -> CheckResult:
        """Match one gray pair, measure it and, with ``auto_refine``, maybe apply a correction."""
        t0, c0 = time.perf_counter(), time.thread_time()
        rig, views, pair = self._geometry()
        opts = self.options
        matches = match_pair(views, left, right, MatchOptions(max_features=opts.max_features))
        fit = self._fit(rig, pair, views, matches, opts.min_matches)
        if fit is None:
            why = (
                f"{len(matches)} matches, need {opts.min_matches}"
                if len(matches) < opts.min_matches
                else f"{len(matches)} matches agree on no relative pose"
            )
            measure = VerticalDisparity(0, None, None, None, 0.0, "not enough matches", why)
            consistent = RayMatches.empty()
        else:
            consistent = matches.select(fit.inliers)
            measure = vertical_disparity(
                pair,
                consistent.left,
                consistent.right,
                min_matches=opts.min_matches,
                min_spread=opts.min_spread,
            )
        now = time.monotonic()
        result = CheckResult(
            now,
            measure,
            len(matches),
            None if fit is None or not measure.ok else fit.rotation_deg,
            (time.perf_counter() - t0) * 1e3,
            (time.thread_time() - c0) * 1e3,
        )
        with self._lock:
            self._counters.checks += 1
            self._counters.without_matches += not measure.ok
            self._counters.history.append(result)
        if opts.auto_refine and measure.ok and result.correction_deg is not None:
            self._pool.matches.append(consistent)
            self._pool.estimates.append(result.correction_deg)
            self._consider_refinement(rig, pair, views)
        return result

    def _fit(
        self, rig: Rig, pair: RectifiedPair, views: EpipolarViews, matches: RayMatches, min_inliers: int
    ) -> RelativePoseFit | None:
        """The rotation-only fit of ``matches`` against ``rig`` (None when they do not support one)."""
        if len(matches) < min_inliers:
            return None
        pose = RelativePoseOptions(
            inlier_threshold_deg=math.degrees(_INLIER_PX / views.px_per_rad),
            estimate_direction="never",
            min_inliers=min_inliers,
        )
        try:
            return refine_relative_pose(
                matches.left,
                matches.right,
                relative_pose(rig, pair.left, pair.right),
                pair.R_cam_rect[pair.left],
                pose,
            )
        except CalibrationFailed:
            return None

    # ----- online refinement -------------------------------------------------------------------
    def _consider_refinement(self, rig: Rig, pair: RectifiedPair, views: EpipolarViews) -> None:
        opts = self.options
        if len(self._pool.estimates) < opts.stable_checks:
            self._set_refinement(
                f"collecting evidence ({len(self._pool.estimates)} of {opts.stable_checks} checks)"
            )
            return
        pooled = RayMatches.concat(list(self._pool.matches))
        fit = self._fit(rig, pair, views, pooled, opts.min_pool_matches)
        if fit is None:
            self._set_refinement(
                f"collecting evidence ({len(pooled)} of {opts.min_pool_matches} pooled matches)"
            )
            return
        new_rig = rig_with_relative_pose(rig, pair.left, pair.right, fit.T_right_left)
        consistent = pooled.select(fit.inliers)
        before = vertical_disparity(pair, consistent.left, consistent.right)
        after = vertical_disparity(self._in_effect().redesigned(new_rig), consistent.left, consistent.right)
        total = drift_deg(self._calibrated, new_rig, pair.left, pair.right)
        why_not = self._unjustified(fit, before, after) or self._too_far(total)
        if why_not is not None:
            self._set_refinement(f"no correction: {why_not}")
            return
        try:
            if self._apply is not None:
                self._apply(new_rig)
        except (RigError, CalibrationError) as err:
            self._set_refinement(f"correction not applied: {err}")
            log.warning("rectification: could not apply a %.3f° correction: %s", fit.angle_deg, err)
            return
        self._pool = _Pool.new(opts.pool_checks)
        self._persist(new_rig)
        with self._lock:
            self.corrections.append(AppliedCorrection(time.monotonic(), fit.angle_deg, total))
        pitch, vergence, roll = fit.rotation_deg
        log.info(
            "rectification: applied a %.3f° ± %.3f° correction of the right camera (about the baseline "
            "%+.3f°, vertical %+.3f°, look direction %+.3f°) from %d matches; vertical disparity p50 "
            "%.2f -> %.2f px",
            fit.angle_deg, fit.angle_sigma_deg, pitch, vergence, roll, fit.n_inliers,
            before.p50_px, after.p50_px,
        )  # fmt: skip
        with self._lock:
            self._counters.corrections += 1
            self._counters.last_correction_deg = fit.angle_deg
            self._counters.refinement = (
                f"applied {fit.angle_deg:.3f}° ± {fit.angle_sigma_deg:.3f}° "
                f"(p50 {before.p50_px:.2f} -> {after.p50_px:.2f} px)"
            )

    def _persist(self, rig: Rig) -> None:
        """Write an applied correction to ``persist_path`` (the original calibration is kept)."""
        path = self.options.persist_path
        if path is None:
            return
        try:
            backup = save_refined(rig, path, self.calibration_path)
        except CalibrationError as err:
            log.warning("rectification: the corrected calibration was not saved: %s", err)
            return
        if backup is not None:
            log.info(
                "rectification: saved the corrected calibration to %s (original kept as %s)", path, backup
            )
        else:
            log.info("rectification: saved the corrected calibration to %s", path)

    def _unjustified(
        self, fit: RelativePoseFit, before: VerticalDisparity, after: VerticalDisparity
    ) -> str | None:
        """Why the pooled correction ``fit`` must not be applied, or None when it may."""
        opts = self.options
        if not (before.ok and after.ok and before.p50_px is not None and after.p50_px is not None):
            return "too few pooled matches inside the rectified pair"
        if fit.angle_deg < 3.0 * fit.angle_sigma_deg:
            return f"{fit.angle_deg:.3f}° is within 3σ ({fit.angle_sigma_deg:.3f}°) of no correction"
        if fit.angle_deg > opts.max_step_deg:
            return f"{fit.angle_deg:.2f}° exceeds max_step_deg {opts.max_step_deg:g}°; recalibrate"
        spread = max(
            float(np.linalg.norm(e - fit.rotation_deg))
            for e in list(self._pool.estimates)[-opts.stable_checks :]
        )
        if spread > opts.stable_deg:
            return f"single checks disagree by up to {spread:.3f}° (stable_deg {opts.stable_deg:g}°)"
        gain = before.p50_px - after.p50_px
        if gain < opts.min_gain_px:
            return (
                f"it would gain only {gain:.2f} px of vertical disparity (min_gain_px {opts.min_gain_px:g})"
            )
        return None

    def _too_far(self, total_deg: float) -> str | None:
        """Why a correction that would put the pair ``total_deg`` from its calibration must not be
        applied (online corrections add up to at most ``max_total_deg``), or None."""
        limit = self.options.max_total_deg
        if total_deg <= limit:
            self._recalibrate = None
            return None
        self._recalibrate = (
            f"recalibrate: the corrections would take camera {self.pair.right} {total_deg:.2f}° from its "
            f"calibration (max_total_deg {limit:g}°)"
        )
        return self._recalibrate

    def _set_refinement(self, text: str) -> None:
        with self._lock:
            changed = self._counters.refinement != text
            self._counters.refinement = text
        if changed:
            log.debug("rectification: %s", text)

    # ----- status ------------------------------------------------------------------------------
    def status(self) -> RectificationStatus:
        """The state from the checks so far (see the module doc)."""
        opts = self.options
        now = time.monotonic()
        with self._lock:
            c = self._counters
            history = list(c.history)
            checks, without, corrections = c.checks, c.without_matches, c.corrections
            last_corr, refinement = c.last_correction_deg, c.refinement
            drift = self.corrections[-1].total_deg if self.corrections else 0.0
        valid = [h for h in history if h.measure.ok]
        last = history[-1] if history else None
        good = valid[-1] if valid else None
        state, reason = rectification_state(last, valid, opts)
        if state == "degraded" and self._recalibrate is not None:
            reason = f"{reason}; {self._recalibrate}"
        figures: dict[str, CounterValue] = {
            "vertical_disparity_p50_px": None if good is None else good.measure.p50_px,
            "vertical_disparity_p95_px": None if good is None else good.measure.p95_px,
            "trend_px_per_hour": p50_trend(valid, now, opts.trend_window_s),
            "degraded": state == "degraded",
            "enough_matches": last is not None and last.measure.ok,
            "matches": None if last is None else last.measure.count,
            "checks": checks,
            "checks_without_enough_matches": without,
            "corrections_applied": corrections,
            "last_correction_deg": last_corr,
            "drift_deg": drift,
            "last_check_age_s": None if last is None else now - last.at_s,
            "check_cpu_ms": None if last is None else last.cpu_ms,
        }
        return RectificationStatus(
            state=state,
            reason=reason,
            auto_refine=opts.auto_refine,
            refinement=refinement if opts.auto_refine else None,
            measured_age_s=None if good is None else now - good.at_s,
            check_wall_ms=None if last is None else last.wall_ms,
            counters=complete("rectification", figures),
        )
