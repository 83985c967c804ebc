"""The service's health: one report from the parts' states, with every reason it is not ``ok``.

``down``: no camera delivers, the worker or the capture is not running. ``degraded``: a camera
out, a camera losing more frames than its limits allow over the rate window
(:mod:`rig.capture.rates`), a calibration that failed its check against the first pair
(:mod:`rig.calibration_check`), valid depth that collapsed (:mod:`rig.depth_watch`), no depth
yet, depth older than ``server.stale_after_s``, a worker error, the active recording stopped
writing, or the rectification off its bound. Else ``ok``. ``/health`` renders it
(service.routes.health).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal, Protocol

from rig.calibration_check import CalibrationCheck
from rig.capture.capture import RigCapture
from rig.capture.health import CaptureHealth
from rig.rectification.monitor import RectificationMonitor, RectificationStatus
from rig.rig_pipeline import RigPipeline
from service.host import HostInfo, host_info
from service.recordings import RecordingManager, RecordingStatus
from service.settings import Settings
from service.store import ResultStore
from service.worker import DepthWorker, WorkerStats

__all__ = ["HealthReport", "HealthSnapshot", "HealthSources", "HealthStatus", "PairHealth", "health_report"]

HealthStatus = Literal["ok", "degraded", "down"]
HealthSnapshot = tuple[bytes, int]
"""A rendered health report, shared by the callers of :meth:`Runtime.health_snapshot`: the
``/health`` body and its HTTP status."""


class HealthSources(Protocol):
    """What the report reads: the parts of a running service (service.runtime.Runtime)."""

    settings: Settings
    capture: RigCapture
    worker: DepthWorker
    store: ResultStore
    ring: RigPipeline | None
    recordings: RecordingManager
    rectification: RectificationMonitor | None
    calibration_check: CalibrationCheck | None
    started_ns: int

    def depth_collapse(self) -> str | None: ...


@dataclass(frozen=True)
class PairHealth:
    """One stereo pair of a rig of N cameras: its cameras, baseline and, on the latest published
    set, the share of its pixels with depth (None before the first set)."""

    cameras: tuple[str, str]
    baseline_m: float
    seq: int | None
    valid_fraction: float | None


@dataclass(frozen=True)
class HealthReport:
    status: HealthStatus
    reasons: list[str]
    uptime_s: float
    capture: CaptureHealth
    worker: WorkerStats
    host: HostInfo
    recording: RecordingStatus | None
    rectification: RectificationStatus | None = None
    pairs: dict[str, PairHealth] | None = None


def _camera_reasons(cap: CaptureHealth) -> list[str]:
    reasons = []
    for name, cam in cap.cameras.items():
        if not cam.connected:
            reasons.append(f"camera {name} {cam.state}: {cam.reason or cam.last_error or 'no frames yet'}")
        elif cam.degraded_reason is not None:
            reasons.append(f"camera {name}: {cam.degraded_reason}")
    return reasons


def _worker_reasons(worker: WorkerStats, stale_after_s: float) -> list[str]:
    reasons = [] if worker.alive else ["depth worker not running"]
    stale_ms = stale_after_s * 1e3
    result_age_ms = worker.counters["last_result_age_ms"]
    if result_age_ms is None:
        reasons.append("no depth frame yet")
    elif result_age_ms > stale_ms:
        reasons.append(f"no depth frame for {result_age_ms / 1e3:.1f} s")
    age = worker.last_error_age_ms
    if worker.last_error is not None and age is not None and age < stale_ms:
        reasons.append(f"depth worker error: {worker.last_error}")
    return reasons


def _depth_reasons(runtime: HealthSources) -> list[str]:
    check = runtime.calibration_check
    reasons = [] if check is None else [f"calibration check: {f.message}" for f in check.errors]
    collapse = runtime.depth_collapse()
    if collapse is not None:
        reasons.append(f"depth: {collapse}")
    return reasons


def health_report(runtime: HealthSources) -> HealthReport:
    """The health of ``runtime`` now (see the module doc)."""
    cap = runtime.capture.health()
    worker = runtime.worker.stats()
    reasons = _camera_reasons(cap) + _worker_reasons(worker, runtime.settings.server.stale_after_s)
    reasons += _depth_reasons(runtime)
    recording = runtime.recordings.active
    if recording is not None and recording.error is not None:
        # The operator asked for this recording and it has stopped writing (e.g. disk full).
        reasons.append(f"recording {recording.name} stopped writing: {recording.error}")
    rectification = None if runtime.rectification is None else runtime.rectification.status()
    if rectification is not None and rectification.state == "degraded":
        reasons.append(f"rectification: {rectification.reason}")
    pairs = _pair_health(runtime)
    for label, pair in (pairs or {}).items():
        if pair.valid_fraction == 0.0:
            reasons.append(f"pair {label}: no depth on the latest set")
    down = not cap.running or not worker.alive or not any(c.connected for c in cap.cameras.values())
    if not cap.running:
        reasons.append("capture not running")
    status: HealthStatus = "down" if down else ("degraded" if reasons else "ok")
    return HealthReport(
        status=status,
        reasons=reasons,
        uptime_s=(time.monotonic_ns() - runtime.started_ns) / 1e9,
        capture=cap,
        worker=worker,
        host=host_info(runtime.settings.server.recordings_dir),
        recording=recording,
        rectification=rectification,
        pairs=pairs,
    )


def _pair_health(runtime: HealthSources) -> dict[str, PairHealth] | None:
    """Each pair of a rig of N cameras on the latest published set (None: a two-camera rig)."""
    if runtime.ring is None:
        return None
    latest = runtime.store.latest
    ring = latest.ring if latest is not None else None
    out = {}
    for label, p in runtime.ring.pipelines.items():
        frame = ring.pairs.get(label) if ring is not None else None
        valid = None if frame is None else float(frame.valid.mean())
        out[label] = PairHealth(p.names, p.baseline_m, None if frame is None else frame.seq, valid)
    return out
