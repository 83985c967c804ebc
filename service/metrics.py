"""Prometheus metrics of one running service, in its own :class:`CollectorRegistry` (never the
global one: several apps may live in one process, e.g. in tests).

Camera, pairing, worker, encode, heap and recording figures are read from the live objects at scrape
time (a custom collector), so they always agree with ``/health``; per-stage processing time is
also a histogram the worker feeds frame by frame.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

from prometheus_client import CollectorRegistry, Histogram, ProcessCollector, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from rig.capture.health import CaptureHealth
from rig.heap import HeapStats
from service.recordings import RecordingStatus
from service.store import PublishedResult
from service.worker import WorkerStats

__all__ = ["CONTENT_TYPE", "MetricsSnapshot", "ServiceMetrics"]

CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"
_STAGE_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.02, 0.035, 0.05, 0.075, 0.1, 0.15, 0.25, 0.5, 1.0, 2.5)


@dataclass(frozen=True)
class MetricsSnapshot:
    capture: CaptureHealth
    worker: WorkerStats
    encodes: dict[str, int]
    recording: RecordingStatus | None
    heap: HeapStats


class _RuntimeCollector(Collector):
    def __init__(self, snapshot: Callable[[], MetricsSnapshot]) -> None:
        self._snapshot = snapshot

    def collect(self) -> Iterator[Metric]:
        s = self._snapshot()
        cams = s.capture.cameras.values()

        def per_camera(
            name: str, doc: str, value: Callable[..., float | None], counter: bool = False
        ) -> Metric:
            fam: GaugeMetricFamily | CounterMetricFamily = (
                CounterMetricFamily(name, doc, labels=["camera"])
                if counter
                else GaugeMetricFamily(name, doc, labels=["camera"])
            )
            for c in cams:
                v = value(c)
                if v is not None:
                    fam.add_metric([c.name], float(v))
            return fam

        yield per_camera("rig_camera_connected", "1 while the camera delivers frames", lambda c: c.connected)
        yield per_camera("rig_camera_fps", "frames per second received", lambda c: c.fps)
        yield per_camera(
            "rig_camera_last_frame_age_seconds",
            "time since the last good frame",
            lambda c: None if c.last_frame_age_ms is None else c.last_frame_age_ms / 1e3,
        )
        yield per_camera("rig_camera_frames_received", "good frames", lambda c: c.frames_received, True)
        yield per_camera(
            "rig_camera_frames_dropped", "lost + unpaired + evicted frames", lambda c: c.frames_dropped, True
        )
        yield per_camera(
            "rig_camera_frames_corrupt", "frames the capture found broken", lambda c: c.frames_corrupt, True
        )
        yield per_camera(
            "rig_camera_frames_undecodable",
            "received frames that did not decode when the depth worker took them",
            lambda c: c.frames_undecodable,
            True,
        )
        yield per_camera("rig_camera_reconnects", "successful reconnects", lambda c: c.reconnects, True)
        yield per_camera(
            "rig_camera_timestamp_errors",
            "frames with implausible timestamps",
            lambda c: c.timestamp_errors,
            True,
        )

        p = s.capture.pairing
        skew = GaugeMetricFamily(
            "rig_pairing_skew_ms", "left-right capture time difference", labels=["quantile"]
        )
        for q, v in (("0.5", p.skew_ms_p50), ("0.95", p.skew_ms_p95)):
            if v is not None:
                skew.add_metric([q], v)
        yield skew
        yield CounterMetricFamily("rig_pairs_formed", "pairs formed by the pairer", value=p.pairs_formed)
        yield CounterMetricFamily(
            "rig_pairs_skipped", "pairs superseded before the worker took them", value=p.pairs_skipped
        )

        w = s.worker
        yield GaugeMetricFamily(
            "rig_worker_alive", "1 while the depth worker thread runs", value=float(w.alive)
        )
        yield GaugeMetricFamily("rig_worker_fps", "depth frames per second", value=w.fps)
        yield CounterMetricFamily("rig_worker_frames", "depth frames published", value=w.frames_processed)
        yield CounterMetricFamily("rig_worker_errors", "pairs that failed to process", value=w.errors)
        if w.latency_ms is not None:
            yield GaugeMetricFamily(
                "rig_worker_latency_ms", "mean processing time per pair", value=w.latency_ms
            )
        if w.age_ms is not None:
            yield GaugeMetricFamily(
                "rig_worker_result_age_ms", "mean time from frame arrival to its depth", value=w.age_ms
            )
        stages = GaugeMetricFamily("rig_stage_latency_ms", "mean time per pipeline stage", labels=["stage"])
        for stage, ms in w.stage_ms.items():
            stages.add_metric([stage], ms)
        yield stages

        enc = CounterMetricFamily(
            "rig_encodes", "response bodies encoded (once per frame and kind)", labels=["kind"]
        )
        for kind, n in sorted(s.encodes.items()):
            enc.add_metric([kind], n)
        yield enc

        # RSS (process_resident_memory_bytes) stays at the working set's high-water mark (the
        # allocator keeps freed blocks): these say whether what is *in use* grows (rig.heap).
        h = s.heap
        if h.malloc_in_use_bytes is not None:
            yield GaugeMetricFamily(
                "rig_malloc_in_use_bytes",
                "bytes malloc has handed out and not had back",
                value=h.malloc_in_use_bytes,
            )
        if h.malloc_free_bytes is not None:
            yield GaugeMetricFamily(
                "rig_malloc_free_bytes", "freed bytes malloc keeps for reuse", value=h.malloc_free_bytes
            )
        yield GaugeMetricFamily(
            "rig_python_allocated_blocks",
            "memory blocks held by Python's object allocator",
            value=h.python_blocks,
        )

        r = s.recording
        yield GaugeMetricFamily(
            "rig_recording_active", "1 while a recording runs", value=float(r is not None)
        )
        if r is not None:
            yield GaugeMetricFamily(
                "rig_recording_pairs", "pairs written to the running recording", value=r.pairs
            )
            yield CounterMetricFamily(
                "rig_recording_dropped", "pairs the running recording could not keep up with", value=r.dropped
            )


class ServiceMetrics:
    """The registry of one runtime; ``observe`` is the worker's per-frame hook."""

    def __init__(self, snapshot: Callable[[], MetricsSnapshot]) -> None:
        self.registry = CollectorRegistry()
        self.stage_seconds = Histogram(
            "rig_stage_seconds",
            "processing time per pipeline stage",
            ["stage"],
            registry=self.registry,
            buckets=_STAGE_BUCKETS,
        )
        self.registry.register(_RuntimeCollector(snapshot))
        ProcessCollector(registry=self.registry)  # process_resident_memory_bytes, CPU seconds, fds

    def observe(self, result: PublishedResult, timings_ms: dict[str, float]) -> None:
        for stage, ms in timings_ms.items():
            self.stage_seconds.labels(stage=stage).observe(ms / 1e3)

    def render(self) -> bytes:
        return generate_latest(self.registry)
