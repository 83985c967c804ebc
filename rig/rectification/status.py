"""The rectification monitor's settings, one check's result and the status ``/health`` reports
(docs/rectification.md): the state from the checks so far and the trend of the median."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import ConfigDict, Field, model_validator

from rig.counters import Counts
from rig.rectification.measure import VerticalDisparity
from rig.settings_model import SettingsModel

__all__ = [
    "CheckResult",
    "RectificationConfig",
    "RectificationState",
    "RectificationStatus",
    "p50_trend",
    "rectification_state",
]

F64 = NDArray[np.float64]

RectificationState = Literal["waiting", "ok", "not enough matches", "degraded"]


class RectificationConfig(SettingsModel):
    """The ``rectification`` settings (see :mod:`rig.rectification.monitor`): the live measure,
    its bounds and the online refinement (lengths in VPC pixels, angles in degrees)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    enabled: bool = Field(True, description="measure the rectification from the frames")
    check_interval_s: float = Field(10.0, ge=0.5, le=3600.0, description="seconds between checks")
    view_px_per_deg: float = Field(
        2.6, ge=0.5, le=20.0, description="resolution of the epipolar views (capped at the lenses')"
    )
    max_features: int = Field(2000, ge=100, le=20000, description="SIFT keypoints per view")
    min_matches: int = Field(50, ge=10, le=100000, description="fewer consistent matches: not enough")
    min_spread: float = Field(
        0.4, ge=0.0, le=1.0, description="share of a 3x3 grid over the VPC image the matches must cover"
    )
    max_p50_px: float = Field(0.5, gt=0.0, description="bound on the vertical disparity's median")
    max_p95_px: float = Field(1.5, gt=0.0, description="bound on its 95th percentile")
    confirm_checks: int = Field(2, ge=1, le=100, description="consecutive checks over a bound: degraded")
    trend_window_s: float = Field(3600.0, gt=0.0, description="window of the p50 trend")
    auto_refine: bool = Field(False, description="apply justified rotation corrections online")
    pool_checks: int = Field(6, ge=1, le=100, description="checks whose matches are pooled")
    min_pool_matches: int = Field(300, ge=30, le=10**6, description="pooled matches needed to correct")
    stable_checks: int = Field(3, ge=1, le=100, description="last checks that must agree")
    stable_deg: float = Field(0.05, gt=0.0, le=5.0, description="how closely they must agree")
    max_step_deg: float = Field(1.0, gt=0.0, le=10.0, description="largest correction applied online")
    max_total_deg: float = Field(
        1.0,
        gt=0.0,
        le=10.0,
        description="largest total drift from the calibration that online corrections may add up to; "
        "beyond it the service says recalibrate",
    )
    min_gain_px: float = Field(0.1, ge=0.0, description="smallest p50 improvement worth a LUT swap")
    persist_path: Path | None = Field(
        None, description="write each applied correction here (rig.yaml, atomically; original kept)"
    )

    @model_validator(mode="after")
    def _stable_within_pool(self) -> RectificationConfig:
        if self.stable_checks > self.pool_checks:
            raise ValueError(
                f"stable_checks ({self.stable_checks}) cannot exceed pool_checks ({self.pool_checks})"
            )
        return self


@dataclass(frozen=True)
class CheckResult:
    """One check: when (``time.monotonic()`` s), its measurement, the matches found, the
    single-check rotation estimate (deg, about the VPC axes; None without a fit) and its cost
    (wall and this thread's CPU, ms)."""

    at_s: float
    measure: VerticalDisparity
    matches: int
    correction_deg: F64 | None
    wall_ms: float
    cpu_ms: float


@dataclass(frozen=True)
class RectificationStatus:
    """What ``/health`` reports under ``rectification``: the state and why, whether the online
    refinement is on and what it is doing, how old the last measurement with enough matches is
    and how long the last check took (wall), and the figures of group ``rectification`` in
    :mod:`rig.counters` (``counters``; the vertical disparity is the last such measurement's)."""

    state: RectificationState
    reason: str | None
    auto_refine: bool
    refinement: str | None
    measured_age_s: float | None
    check_wall_ms: float | None
    counters: Counts

    def _float(self, name: str) -> float | None:
        value = self.counters[name]
        return None if value is None else float(value)

    @property
    def p50_px(self) -> float | None:
        return self._float("vertical_disparity_p50_px")

    @property
    def p95_px(self) -> float | None:
        return self._float("vertical_disparity_p95_px")

    @property
    def trend_px_per_hour(self) -> float | None:
        return self._float("trend_px_per_hour")

    @property
    def check_cpu_ms(self) -> float | None:
        return self._float("check_cpu_ms")

    @property
    def matches(self) -> int | None:
        value = self.counters["matches"]
        return None if value is None else int(value)

    @property
    def checks(self) -> int:
        return int(self.counters["checks"] or 0)

    @property
    def checks_without_enough_matches(self) -> int:
        return int(self.counters["checks_without_enough_matches"] or 0)

    @property
    def corrections_applied(self) -> int:
        return int(self.counters["corrections_applied"] or 0)


def rectification_state(
    last: CheckResult | None, valid: list[CheckResult], opts: RectificationConfig
) -> tuple[RectificationState, str | None]:
    """The state and its reason from the last check and the checks with enough matches: a check
    without enough matches is never a verdict; ``degraded`` takes ``confirm_checks`` over a bound."""
    if last is None:
        return "waiting", "no check yet"
    if not last.measure.ok:
        return "not enough matches", last.measure.reason
    recent = valid[-opts.confirm_checks :]
    over = [h for h in recent if _over(h.measure, opts)]
    if len(recent) == opts.confirm_checks and len(over) == len(recent):
        m = last.measure
        return "degraded", (
            f"vertical disparity p50 {m.p50_px:.2f} px, p95 {m.p95_px:.2f} px over the bound "
            f"({opts.max_p50_px:g} / {opts.max_p95_px:g} px) in {len(recent)} checks"
        )
    return "ok", None


def _over(m: VerticalDisparity, opts: RectificationConfig) -> bool:
    return (
        m.p50_px is not None
        and m.p95_px is not None
        and (m.p50_px > opts.max_p50_px or m.p95_px > opts.max_p95_px)
    )


def p50_trend(valid: list[CheckResult], now: float, window_s: float) -> float | None:
    """Least-squares slope of p50 (px per hour) over the valid checks within ``window_s``."""
    pts = [
        (h.at_s, h.measure.p50_px) for h in valid if now - h.at_s <= window_s and h.measure.p50_px is not None
    ]
    if len(pts) < 3:
        return None
    t = np.array([p[0] for p in pts])
    y = np.array([p[1] for p in pts])
    if np.ptp(t) <= 0:
        return None
    slope = float(np.polyfit(t - t[0], y, 1)[0])
    return slope * 3600.0
