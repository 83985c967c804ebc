"""Everything a running service holds: calibration, pipeline, capture, worker, result store,
recordings and metrics, built from :class:`~service.settings.Settings` and started/stopped as one.

:meth:`Runtime.build` does all the fallible work (calibration file, LUTs, opening the recording
of file cameras) before anything starts, so a bad configuration is one error, not a half-running
service. :meth:`Runtime.stop` joins the worker, finishes a running recording and joins the
capture threads.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Collection
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from calibration import load_rig
from calibration.rig import Rig
from rig import priority
from rig.calibration_check import CalibrationCheck, check_calibration
from rig.capture.capture import RigCapture
from rig.capture.config import FileCameraConfig
from rig.capture.recorded import open_recording
from rig.depth_watch import Coverage, DepthWatch
from rig.errors import CorruptFrameError
from rig.heap import heap_stats
from rig.in_effect import PairInEffect
from rig.memory_budget import MIB, MemoryEstimate
from rig.pinhole_depth import PinholeDepthView
from rig.pipeline import DepthPipeline
from rig.rectification.monitor import RectificationMonitor
from rig.rectified import design_rectified_pair
from rig.rig_pipeline import RigPipeline
from rig.stereo import StereoParams
from service.encoders import confidence_png, depth_png, disparity_png, npy_bytes
from service.errors import ConfigChanged, SettingsError, StereoParamsRefused, TooManyStreams
from service.health_report import HealthReport, HealthSnapshot, health_report
from service.memo import DocumentMemo
from service.memory import check_memory, ring_estimate, service_estimate
from service.metrics import MetricsSnapshot, ServiceMetrics
from service.recordings import RecordingManager
from service.rig_setup import check_sizes, check_two_cameras, resolve_calibration, ring_pipeline
from service.settings import Settings
from service.store import PublishedResult, ResultStore
from service.worker import DepthWorker

__all__ = ["Runtime", "etag", "resolve_calibration"]

log = logging.getLogger("service.runtime")


_NONE = Coverage(0.0, 0.0, 0)


def etag(revision: int) -> str:
    """The ETag of the configuration at ``revision`` (``/config``)."""
    return f'"{revision}"'


class Runtime:
    """The running parts of one service (see module doc)."""

    def __init__(
        self,
        settings: Settings,
        rig: Rig,
        pipeline: DepthPipeline,
        capture: RigCapture,
        calibration_path: Path | None = None,
        ring: RigPipeline | None = None,
    ) -> None:
        self.settings = settings
        self.rig = rig
        self.pipeline = pipeline  # a rig of N cameras: its first pair's (ring holds them all)
        self.ring = ring
        self.capture = capture
        self.calibration_path = calibration_path
        self.store = ResultStore()
        self.recordings = RecordingManager(
            settings.server.recordings_dir,
            queue_size=settings.server.recording_queue,
            rig=rig,
            cameras=capture.names,
        )
        self.metrics = ServiceMetrics(self.metrics_snapshot)
        scale, level = settings.server.depth_scale_m, settings.server.png_compression
        # The /depth, /range, /disparity and /confidence bodies by cache key: the routes encode them on
        # request and the worker ahead of the clients that poll them (one table, so they cannot
        # disagree).
        self.frame_bodies: dict[str, Callable[[PublishedResult], bytes]] = {
            "depth_png": lambda r: depth_png(r.frame.depth, scale, level),
            "depth_npy": lambda r: npy_bytes(r.frame.depth),
            "range_png": lambda r: depth_png(r.frame.range, scale, level),
            "range_npy": lambda r: npy_bytes(r.frame.range),
            "pinhole_depth_png": lambda r: depth_png(self.pinhole_depth(r), scale, level),
            "pinhole_depth_npy": lambda r: npy_bytes(self.pinhole_depth(r)),
            "disparity_png": lambda r: disparity_png(r.frame.disparity, level),
            "disparity_npy": lambda r: npy_bytes(r.frame.disparity),
            "confidence_png": lambda r: confidence_png(r.confidence(), level),
            "confidence_npy": lambda r: npy_bytes(r.confidence()),
        }
        self.worker = DepthWorker(
            capture,
            pipeline,
            self.store,
            on_pair=self.recordings.offer,
            on_result=self._observe,
            prefetch=self.frame_bodies,
            ring=ring,
        )
        self.rectification: RectificationMonitor | None = None
        if settings.rectification.enabled:
            self.rectification = RectificationMonitor(
                lambda: self.pipeline.in_effect,
                self._latest_gray_pair,
                settings.rectification,
                apply=self._apply_corrected_rig,
                calibration_path=calibration_path,
                cache_dir=settings.cache_dir,
            )
        self.started_ns = time.monotonic_ns()
        self.documents = DocumentMemo()  # /calibration's response, made once per calibration
        # The calibration checked against the first processed pair (rig.calibration_check), and
        # against the pair where the depth collapsed (rig.depth_watch), for its likely cause.
        self.calibration_check: CalibrationCheck | None = None
        self.collapse_check: CalibrationCheck | None = None
        watch = settings.depth_watch
        self.depth_watch = DepthWatch(
            recent_s=watch.recent_s, reference_s=watch.reference_s, collapse_ratio=watch.collapse_ratio
        )
        self._collapse: str | None = None
        self._collapse_checked_at = -1e9
        self._check_started = False
        self._check_lock = threading.Lock()
        self._running = False
        self._health_lock = threading.Lock()
        self._health_memo: tuple[float, object, HealthSnapshot] | None = None
        # Configuration changes are serialised (check the revision, validate, apply as one step);
        # readers take the pair in effect without waiting.
        self._config_lock = threading.Lock()
        self._streams_lock = threading.Lock()
        self._streams_open = 0  # /stream.mjpg responses running

    @classmethod
    def build(cls, settings: Settings) -> Runtime:
        """Load the calibration, build the pipeline (LUTs from the cache) and the capture."""
        if settings.cameras is None:
            raise SettingsError(
                "settings: field 'cameras': no cameras configured (give --config, --recording or --demo)"
            )
        calibration = resolve_calibration(settings)
        rig = load_rig(calibration)
        stereo = settings.stereo
        ring = ring_pipeline(settings, rig, calibration) if len(rig.names) > 2 else None
        if ring is None:
            check_two_cameras(settings, rig, calibration)
            # Before any table is built: a size that cannot fit is refused with the reason.
            planned = design_rectified_pair(rig, settings.rectified, blind_band_px=stereo.blind_band_px)
            check_memory(service_estimate(settings, rig, planned, stereo), planned, stereo)
            pipeline = DepthPipeline(rig, settings.rectified, stereo, cache_dir=settings.cache_dir)
        else:
            pipeline = ring.first
        for name in settings.cameras.names:
            cam = settings.cameras.camera(name)
            if isinstance(cam, FileCameraConfig):
                # RecordingError naming the file (or bag topic), before any thread starts.
                open_recording(
                    cam.recording,
                    left_topic=cam.left_topic,
                    right_topic=cam.right_topic,
                    max_skew_ms=cam.max_skew_ms,
                    topics=cam.topics,
                )
        capture = RigCapture(settings.cameras)
        check_sizes(settings.cameras, capture, rig)
        return cls(settings, rig, pipeline, capture, calibration, ring)

    # ----- lifecycle ---------------------------------------------------------------------------
    def start(self) -> None:
        if self._running:
            return
        self._running = True
        self.started_ns = time.monotonic_ns()
        # Before the threads start: each depth thread takes its priority first thing.
        priority.configure(self.settings.server.depth_nice)
        self.capture.start()
        self.worker.start()
        priority.prioritise_native_threads()  # OpenCV's pool, if the main thread started it
        if self.rectification is not None:
            self.rectification.start()
        budget = self.memory_budget
        log.info(
            "depth service running: rectified pair %s, baseline %.4f m; memory budget %.0f MiB (%s)",
            self.pipeline.pair.as_json(),
            self.pipeline.baseline_m,
            budget.total / MIB,
            budget.largest(),
        )

    def stop(self) -> None:
        """Join the rectification monitor and the worker, finish a running recording, join the
        capture threads; idempotent."""
        if self.rectification is not None:
            self.rectification.stop()
        self.worker.stop()
        self.recordings.close()
        self.capture.stop()
        self._running = False

    # ----- the calibration against the first pair, the depth watch ----------------------------
    def _observe(self, result: PublishedResult, timings_ms: dict[str, float]) -> None:
        """Each published result: metrics and the depth watch; the first one also starts the
        calibration check, and a collapse of the depth looks for its likely cause."""
        self.metrics.observe(result, timings_ms)
        now = self.pipeline.in_effect
        watch = self.depth_watch
        at = time.monotonic()
        watch.observe(at, watch.coverage(result.frame.valid, now), now.revision)
        with self._check_lock:
            first, self._check_started = not self._check_started, True
            verdict = self._collapse
            if at - self._collapse_checked_at >= 1.0:  # judged once a second, not every frame
                verdict, self._collapse_checked_at = watch.verdict(at), at
            started = verdict is not None and self._collapse is None
            ended = verdict is None and self._collapse is not None
            self._collapse = verdict
        if first:
            self._in_background(self._check_calibration, result, "")
        if started:
            log.warning("depth: %s", verdict)
            self._in_background(self._check_calibration, result, ", where depth collapsed")
        if ended:
            log.info("depth: recovered (%.0f %% of the overlap)", 100 * (watch.latest() or _NONE).share)
            self.collapse_check = None

    @staticmethod
    def _in_background(
        check: Callable[[PublishedResult, str], None], result: PublishedResult, what: str
    ) -> None:
        threading.Thread(target=check, args=(result, what), name="rig-calibration-check", daemon=True).start()

    def _check_calibration(self, result: PublishedResult, what: str) -> None:
        """Off the worker's threads (feature matching takes a while): errors are logged once and
        stay in /health's reasons; warnings are logged once. On the first pair it is the
        calibration check; on a pair where depth collapsed, the likely cause."""
        try:
            check = check_calibration(self.pipeline, result.left.gray, result.right.gray, result.frame)
        except Exception as err:  # a diagnostic must never stop the service
            log.warning("calibration check on pair %d%s failed: %s", result.frame.seq, what, err)
            return
        if self.calibration_check is None:
            self.calibration_check = check
        else:
            self.collapse_check = check
        for finding in check.findings:
            level = logging.ERROR if finding.severity == "error" else logging.WARNING
            log.log(level, "calibration check on pair %d%s: %s", result.frame.seq, what, finding.message)

    def depth_collapse(self) -> str | None:
        """The depth watch's verdict with its likely cause, or None while depth keeps coming."""
        verdict = self._collapse
        if verdict is None:
            return None
        check = self.collapse_check
        causes = [] if check is None else [f.message for f in check.errors]
        return verdict + (f"; likely cause: {'; '.join(causes)}" if causes else "")

    # ----- rectification -----------------------------------------------------------------------
    def _latest_gray_pair(self) -> tuple[NDArray[np.uint8], NDArray[np.uint8]] | None:
        """The newest published pair's luma (decoded by the worker already), for the monitor."""
        result = self.store.latest
        if result is None:
            return None
        try:
            return result.left.gray, result.right.gray
        except CorruptFrameError:
            return None

    def _apply_corrected_rig(self, rig: Rig) -> None:
        """An online correction: new lookup tables swapped into the running pipeline (built on
        the monitor's thread, the worker keeps going), and the rig everything else reports."""
        self.pipeline.apply(rig=rig)
        self.rig = rig
        self.recordings.rig = rig

    # ----- configuration changes ---------------------------------------------------------------
    def change_stereo(
        self, merge: Callable[[StereoParams], StereoParams], if_match: Collection[str] | None = None
    ) -> PairInEffect:
        """Apply ``merge(parameters in effect)`` to the pipeline, serialised with every other
        change: only when the pair in effect's revision is one of the ETags ``if_match``
        (``'"3"'``; ConfigChanged otherwise), and only when the budget of the new parameters
        fits the memory the machine has left once the current budget is given back
        (StereoParamsRefused otherwise). Returns the new pair in effect: every pair matched after
        this returns uses it."""
        with self._config_lock:
            now = self.pipeline.in_effect
            current = etag(now.revision)
            if if_match is not None and current not in if_match:
                raise ConfigChanged(
                    f"the configuration is at revision {current}, not {', '.join(if_match)}: "
                    "GET /config and apply the change to what it shows"
                )
            params = merge(now.stereo)
            estimate = self._estimate(params)
            try:
                check_memory(estimate, now.pair, params, already_held=self.memory_budget.total)
            except SettingsError as err:
                raise StereoParamsRefused(str(err).removeprefix("settings: field 'rectified': ")) from err
            if self.ring is not None:  # every pair of the rig, the first (the revision) last
                for p in list(self.ring.pipelines.values())[1:]:
                    p.apply(stereo=params)
            return self.pipeline.apply(stereo=params)

    def pinhole_view(self) -> PinholeDepthView:
        """The pinhole depth image of the pair in effect (made once per pair design)."""
        pair = self.pipeline.in_effect.pair
        return self.documents.get(
            "pinhole_depth", pair, lambda: PinholeDepthView(pair, self.settings.pinhole_depth)
        )

    def pinhole_depth(self, result: PublishedResult) -> NDArray[np.float32]:
        """``result``'s range as z on the pinhole depth image (rig.pinhole_depth)."""
        return self.pinhole_view().depth(result.frame.range)

    def open_stream(self) -> None:
        """Count a ``/stream.mjpg`` response in; TooManyStreams at ``server.max_streams``."""
        limit = self.settings.server.max_streams
        with self._streams_lock:
            if self._streams_open >= limit:
                raise TooManyStreams(f"{limit} clients are streaming already (server.max_streams); try later")
            self._streams_open += 1

    def close_stream(self) -> None:
        with self._streams_lock:
            self._streams_open -= 1

    @property
    def streams_open(self) -> int:
        return self._streams_open

    @property
    def memory_budget(self) -> MemoryEstimate:
        """The budget of the pair (every pair and the panorama of a rig of N cameras) and stereo
        parameters in effect (a change re-estimates it)."""
        return self._estimate(self.pipeline.in_effect.stereo)

    def _estimate(self, stereo: StereoParams) -> MemoryEstimate:
        if self.ring is None:
            return service_estimate(self.settings, self.rig, self.pipeline.in_effect.pair, stereo)
        pairs = [p.in_effect.pair for p in self.ring.pipelines.values()]
        panorama = self.ring.panorama.camera
        return ring_estimate(self.settings, self.rig, pairs, stereo, (panorama.width, panorama.height))

    # ----- state -------------------------------------------------------------------------------
    def metrics_snapshot(self) -> MetricsSnapshot:
        return MetricsSnapshot(
            capture=self.capture.health(),
            worker=self.worker.stats(),
            encodes=self.store.counter.snapshot(),
            recording=self.recordings.active,
            heap=heap_stats(),
            rectification=None if self.rectification is None else self.rectification.status(),
            memory_budget_bytes=self.memory_budget.total,
        )

    def health_snapshot(
        self, render: Callable[[HealthReport], HealthSnapshot], max_age_s: float
    ) -> HealthSnapshot:
        """``render(self.health())``, shared by callers within ``max_age_s`` and built by one of
        them at a time: under many clients ``/health`` costs one build per interval, not one per
        request (each build holds the GIL the depth worker needs). Starting or stopping a
        recording shows at once (it is part of the memo's key); camera faults show within
        ``max_age_s``."""
        with self._health_lock:
            value = self.fresh_health_snapshot(max_age_s)
            if value is None:
                value = render(self.health())
                self._health_memo = (time.monotonic(), self._health_key(), value)
            return value

    def fresh_health_snapshot(self, max_age_s: float) -> HealthSnapshot | None:
        """The last :meth:`health_snapshot` if it is still fresh (no I/O, never blocks), else None."""
        memo = self._health_memo
        if memo is not None and time.monotonic() - memo[0] <= max_age_s and memo[1] == self._health_key():
            return memo[2]
        return None

    def _health_key(self) -> object:
        active = self.recordings.active
        return None if active is None else (active.name, active.error)

    def health(self) -> HealthReport:
        """The service's health now (:func:`service.health_report.health_report`)."""
        return health_report(self)
