"""Prometheus metrics of one running service, in its own :class:`CollectorRegistry` (never the
global one: several apps may live in one process, e.g. in tests).

Camera, pairing, worker, rectification, encode, heap and recording figures are read from the
live objects at scrape time (a custom collector), so they always agree with ``/health``; the
camera, pairing, worker and rectification metrics are those of the counter table
(:mod:`rig.counters`). Per-stage processing time is also a histogram the worker feeds frame by
frame.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

from prometheus_client import CollectorRegistry, Histogram, ProcessCollector, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from rig.capture.health import CaptureHealth
from rig.counters import Counts, Group, counters_of
from rig.heap import HeapStats
from rig.rectification.monitor import RectificationStatus
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
    rectification: RectificationStatus | None = None
    memory_budget_bytes: int | None = None


class _RuntimeCollector(Collector):
    def __init__(self, snapshot: Callable[[], MetricsSnapshot]) -> None:
        self._snapshot = snapshot

    def collect(self) -> Iterator[Metric]:
        s = self._snapshot()
        cams = [((c.name,), c.counters) for c in s.capture.cameras.values()]
        yield from _counter_families("camera", cams, ("camera",))
        yield from _counter_families("pairing", [((), s.capture.pairing.counters)])
        w = s.worker
        yield from _counter_families("worker", [((), w.counters)])
        if s.rectification is not None:
            yield from _counter_families("rectification", [((), s.rectification.counters)])
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
        if s.memory_budget_bytes is not None:
            yield GaugeMetricFamily(
                "rig_memory_budget_bytes",
                "the resident size the service's settings allow (estimated at start-up; service.memory)",
                value=s.memory_budget_bytes,
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


def _counter_families(
    group: Group, rows: Sequence[tuple[tuple[str, ...], Counts]], label_names: tuple[str, ...] = ()
) -> Iterator[Metric]:
    """One family per Prometheus metric of ``group`` in the counter table (:mod:`rig.counters`):
    a sample per row (its ``label_names`` values and counters) and the entry's fixed labels;
    null figures have no sample."""
    families: dict[str, CounterMetricFamily | GaugeMetricFamily] = {}
    for spec in counters_of(group):
        fixed = spec.metric_labels
        family = families.get(spec.metric_family)
        if family is None:
            kind = CounterMetricFamily if spec.kind == "counter" else GaugeMetricFamily
            labels = [*label_names, *(k for k, _ in fixed)]
            family = families[spec.metric_family] = kind(spec.metric_family, spec.help, labels=labels)
        for label_values, counts in rows:
            value = counts[spec.name]
            if value is not None:
                family.add_metric([*label_values, *(v for _, v in fixed)], float(value) * spec.metric_scale)
    yield from families.values()


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
