"""The counter table: every camera, pairing, depth-worker and rectification figure, declared once.

Each :class:`CounterSpec` names one figure (a ``counter`` only ever grows; a ``gauge`` is a
current value), its unit, its meaning and its group. The table feeds everything that shows the
figures: the health snapshots (:mod:`rig.capture.health`, the worker's stats), the ``/health``
schema (one field per entry, described by its help and unit), ``/metrics`` (one Prometheus
sample per entry; label ``camera`` for the camera group), ``GET /counters`` and the dashboard's
camera table (entries with a ``column``), and ``docs/counters.md`` (``python -m rig.counters``).

Adding a figure: add its :class:`CounterSpec` to :data:`COUNTERS` and count it. A plain counter
of the camera or worker group is kept by a :class:`Tally` (``tally.add(name)`` where it
happens); a gauge, and the pairing and rectification figures, are measured where the snapshot
is made (``CameraSupervisor.health``, ``StereoCapture.health``, ``DepthWorker.stats``,
``RectificationMonitor.status``); a counter with
``sum_of`` is the sum of others and needs no code. :func:`complete` refuses a snapshot that
misses a declared figure or has an undeclared one, so the table and the counting code cannot
drift apart. Then regenerate ``docs/counters.md`` (a test compares it with :func:`markdown`).
"""

from __future__ import annotations

import dataclasses
import functools
import sys
from collections.abc import Mapping
from typing import Any, Literal

__all__ = [
    "COUNTERS",
    "GROUPS",
    "CounterSpec",
    "CounterValue",
    "Counts",
    "Group",
    "Kind",
    "Tally",
    "complete",
    "counters_of",
    "flatten",
    "markdown",
]

Kind = Literal["counter", "gauge"]
Group = Literal["camera", "pairing", "worker", "rectification"]
GROUPS: tuple[Group, ...] = ("camera", "pairing", "worker", "rectification")
CounterValue = int | float | bool | None
#: One group's figures by name, in table order (a snapshot's ``counters``).
Counts = dict[str, CounterValue]

# Prometheus names are this prefix + the name unless an entry names its metric.
_METRIC_PREFIX: dict[Group, str] = {
    "camera": "rig_camera_",
    "pairing": "rig_",
    "worker": "rig_worker_",
    "rectification": "rig_rectification_",
}


@dataclasses.dataclass(frozen=True)
class CounterSpec:
    """One figure. ``value`` is its JSON type in ``/health`` (``optional``: null until measured).
    ``sum_of``: a counter that is the sum of these others of its group. ``metric``,
    ``metric_labels`` and ``metric_scale`` override the Prometheus sample (entries that share a
    ``metric`` are one family told apart by their labels). ``column``: the dashboard's camera
    table shows it in this column (entries with the same column are summed), with ``digits``
    decimals."""

    name: str
    group: Group
    kind: Kind
    unit: str
    help: str
    value: type[int] | type[float] | type[bool] = int
    optional: bool = False
    sum_of: tuple[str, ...] = ()
    metric: str | None = None
    metric_labels: tuple[tuple[str, str], ...] = ()
    metric_scale: float = 1.0
    column: str | None = None
    digits: int = 0

    @property
    def metric_family(self) -> str:
        """The Prometheus metric (family) name."""
        return self.metric or _METRIC_PREFIX[self.group] + self.name

    @property
    def metric_sample(self) -> str:
        """The sample name as scraped (counters get ``_total``)."""
        return self.metric_family + ("_total" if self.kind == "counter" else "")

    @property
    def metric_selector(self) -> str:
        """The sample with its fixed labels, as a PromQL selector."""
        labels = ", ".join(f'{k}="{v}"' for k, v in self.metric_labels)
        return f"{self.metric_sample}{{{labels}}}" if labels else self.metric_sample


def _camera(name: str, kind: Kind, unit: str, help: str, **more: Any) -> CounterSpec:
    return CounterSpec(name, "camera", kind, unit, help, **more)


def _pairing(name: str, kind: Kind, unit: str, help: str, **more: Any) -> CounterSpec:
    return CounterSpec(name, "pairing", kind, unit, help, **more)


def _worker(name: str, kind: Kind, unit: str, help: str, **more: Any) -> CounterSpec:
    return CounterSpec(name, "worker", kind, unit, help, **more)


def _rectification(name: str, kind: Kind, unit: str, help: str, **more: Any) -> CounterSpec:
    return CounterSpec(name, "rectification", kind, unit, help, **more)


_SKEW = "rig_pairing_skew_ms"
_VERTICAL = "rig_rectification_vertical_disparity_px"

#: The table. Order is the order of ``/health`` fields, ``/metrics`` families, the docs and the
#: dashboard's columns.
COUNTERS: tuple[CounterSpec, ...] = (
    # ----- per camera (rig.capture.supervisor counts, rig.capture.pairing drops) --------------
    _camera("connected", "gauge", "bool", "1 while the camera is available (delivering frames)", value=bool),
    _camera(
        "fps",
        "gauge",
        "frames/s",
        "good frames per second over the last cameras.supervisor.fps_window_s",
        value=float,
        column="fps",
        digits=1,
    ),
    _camera(
        "frames_received",
        "counter",
        "frames",
        "frames that passed validation and the timestamp checks and went to pairing",
    ),
    _camera(
        "frames_dropped",
        "counter",
        "frames",
        "frames that never became part of a depth pair: lost + unpaired + evicted",
        sum_of=("frames_lost", "frames_unpaired", "frames_evicted"),
        column="dropped",
    ),
    _camera(
        "frames_lost",
        "counter",
        "frames",
        "gaps in the camera's seq: frames the camera or driver never delivered "
        "(a seq that goes down starts a new stream and counts nothing)",
    ),
    _camera(
        "frames_unpaired",
        "counter",
        "frames",
        "received frames dropped by pairing because no partner was within the skew gate",
    ),
    _camera(
        "frames_evicted",
        "counter",
        "frames",
        "received frames pushed out of the camera's full pairing buffer",
    ),
    _camera(
        "frames_corrupt",
        "counter",
        "frames",
        "frames the camera's thread found broken (JPEG structure, or a luma decode where that "
        "thread decodes, per cameras.supervisor.decode); they never reach pairing",
        column="broken",
    ),
    _camera(
        "frames_undecodable",
        "counter",
        "frames",
        "received frames whose luma did not decode when the depth worker took them "
        "(0 with cameras.supervisor.decode: true)",
        column="broken",
    ),
    _camera(
        "timestamp_errors",
        "counter",
        "frames",
        "frames refused because a host-clock timestamp was more than max_clock_offset_ms before "
        "the read that took the frame, more than max_future_ms after its arrival, or did not "
        "increase; each triggers a reconnect",
    ),
    _camera(
        "corrupt_per_s",
        "gauge",
        "frames/s",
        "frames found corrupt per second over the last cameras.supervisor.rate_window_s "
        "(null until the window holds enough frames)",
        value=float,
        optional=True,
    ),
    _camera(
        "undecodable_per_s",
        "gauge",
        "frames/s",
        "frames found undecodable per second over the same window",
        value=float,
        optional=True,
    ),
    _camera(
        "dropped_per_s",
        "gauge",
        "frames/s",
        "frames dropped (lost, unpaired or evicted) per second over the same window",
        value=float,
        optional=True,
    ),
    _camera("reconnects", "counter", "reconnects", "successful re-opens of the camera after an outage"),
    _camera("reconnect_attempts", "counter", "attempts", "re-opens of the camera tried after an outage"),
    _camera("usb_resets", "counter", "resets", "USB resets of the device after failed reconnects"),
    _camera(
        "last_frame_age_ms",
        "gauge",
        "ms",
        "time since the last good frame (null before the first)",
        value=float,
        optional=True,
        metric="rig_camera_last_frame_age_seconds",
        metric_scale=1e-3,
        column="last frame (ms)",
    ),
    # ----- pairing (rig.capture.capture) ------------------------------------------------------
    _pairing(
        "skew_ms",
        "gauge",
        "ms",
        "median |left - right| capture time difference over the last pairing.skew_window pairs",
        value=float,
        optional=True,
        metric=_SKEW,
        metric_labels=(("quantile", "0.5"),),
    ),
    _pairing(
        "skew_ms_p95",
        "gauge",
        "ms",
        "95th percentile of |left - right| capture time difference over the same pairs",
        value=float,
        optional=True,
        metric=_SKEW,
        metric_labels=(("quantile", "0.95"),),
    ),
    _pairing(
        "pairs_formed",
        "counter",
        "pairs",
        "pairs formed by the pairer: taken + skipped + evicted + pending",
    ),
    _pairing("pairs_taken", "counter", "pairs", "pairs the depth worker (or recorder) took"),
    _pairing(
        "pairs_skipped",
        "counter",
        "pairs",
        "pairs superseded by a newer one before the worker, which asks for the newest, took them",
    ),
    _pairing("pairs_evicted", "counter", "pairs", "pairs pushed out of the full pair buffer"),
    _pairing("pairs_pending", "gauge", "pairs", "pairs waiting in the pair buffer"),
    # ----- depth worker (service.worker) ------------------------------------------------------
    _worker("alive", "gauge", "bool", "1 while the depth worker's threads run", value=bool),
    _worker("fps", "gauge", "frames/s", "depth frames published per second over the last 2 s", value=float),
    _worker(
        "processing_ms",
        "gauge",
        "ms",
        "mean processing time per pair, decode to depth (the sum of the stages), over the recent frames",
        value=float,
        optional=True,
    ),
    _worker(
        "latency_ms",
        "gauge",
        "ms",
        "processing_ms under its first name (kept for clients that read it): not the frame's age",
        value=float,
        optional=True,
    ),
    _worker(
        "age_ms",
        "gauge",
        "ms",
        "mean time from a frame's arrival to its depth being published, over the recent frames",
        value=float,
        optional=True,
        metric="rig_worker_result_age_ms",
    ),
    _worker(
        "last_result_age_ms",
        "gauge",
        "ms",
        "time since the last depth frame was published (null before the first)",
        value=float,
        optional=True,
    ),
    _worker("frames_processed", "counter", "frames", "depth frames published", metric="rig_worker_frames"),
    _worker(
        "searches_kept",
        "counter",
        "frames",
        "depth frames whose matching kept the last search whole: nothing had changed since "
        "(stereo.temporal_prior; docs/stereo.md)",
    ),
    _worker(
        "errors",
        "counter",
        "pairs",
        "pairs that failed to process (a frame that does not decode counts against its camera instead)",
    ),  # ----- rectification (rig.rectification.monitor; docs/rectification.md) --------------------
    _rectification(
        "vertical_disparity_p50_px",
        "gauge",
        "px",
        "median |v_left - v_right| of the last check's consistent matches in the rectified pair (null "
        "until a check had enough matches; then the last such check's)",
        value=float,
        optional=True,
        metric=_VERTICAL,
        metric_labels=(("quantile", "0.5"),),
    ),
    _rectification(
        "vertical_disparity_p95_px",
        "gauge",
        "px",
        "95th percentile of the same",
        value=float,
        optional=True,
        metric=_VERTICAL,
        metric_labels=(("quantile", "0.95"),),
    ),
    _rectification(
        "trend_px_per_hour",
        "gauge",
        "px/h",
        "slope of the median over the checks of rectification.trend_window_s (null with fewer than 3)",
        value=float,
        optional=True,
    ),
    _rectification(
        "degraded",
        "gauge",
        "bool",
        "1 while the last rectification.confirm_checks checks were over max_p50_px or max_p95_px",
        value=bool,
    ),
    _rectification(
        "enough_matches",
        "gauge",
        "bool",
        "1 when the last check had enough consistent, spread-out matches to measure",
        value=bool,
    ),
    _rectification(
        "matches",
        "gauge",
        "matches",
        "consistent matches inside the rectified pair in the last check (null before the first)",
        optional=True,
        value=int,
    ),
    _rectification("checks", "counter", "checks", "rectification checks run"),
    _rectification(
        "checks_without_enough_matches",
        "counter",
        "checks",
        "checks that could not measure: too few matches, or bunched in one place (never an alarm)",
    ),
    _rectification(
        "corrections_applied",
        "counter",
        "corrections",
        "online rotation corrections applied (rectification.auto_refine), lookup tables swapped",
    ),
    _rectification(
        "last_correction_deg",
        "gauge",
        "deg",
        "angle of the last correction applied online (null before the first)",
        value=float,
        optional=True,
    ),
    _rectification(
        "drift_deg",
        "gauge",
        "deg",
        "the pair's total rotation from its calibration after the corrections applied online "
        "(bounded by rectification.max_total_deg: beyond it, recalibrate)",
        value=float,
    ),
    _rectification(
        "last_check_age_s",
        "gauge",
        "s",
        "time since the last check (null before the first)",
        value=float,
        optional=True,
    ),
    _rectification(
        "check_cpu_ms",
        "gauge",
        "ms",
        "CPU time of the last check on the monitor's thread (OpenCV's pool adds some)",
        value=float,
        optional=True,
    ),
)


@functools.cache
def _grouped(table: tuple[CounterSpec, ...]) -> dict[Group, tuple[CounterSpec, ...]]:
    _check(table)
    return {g: tuple(c for c in table if c.group == g) for g in GROUPS}


def _check(table: tuple[CounterSpec, ...]) -> None:
    """A table the code can derive everything from, or ValueError naming the entry."""
    plain = {(c.group, c.name) for c in table if c.kind == "counter" and not c.sum_of}
    if len({(c.group, c.name) for c in table}) != len(table):
        raise ValueError("a counter is declared twice in its group")
    for c in table:
        where = f"counter {c.group}.{c.name}"
        if c.group not in GROUPS or c.kind not in ("counter", "gauge"):
            raise ValueError(f"{where}: unknown group {c.group!r} or kind {c.kind!r}")
        if c.kind == "counter" and (c.value is not int or c.optional):
            raise ValueError(f"{where}: a counter is a non-null integer")
        if any((c.group, part) not in plain for part in c.sum_of):
            raise ValueError(f"{where}: sum_of names what is not a plain counter of its group")
    families: dict[str, list[CounterSpec]] = {}
    for c in table:
        families.setdefault(c.metric_family, []).append(c)
    for name, family in families.items():
        first, keys = family[0], [k for k, _ in family[0].metric_labels]
        alike = all(
            (c.group, c.kind, [k for k, _ in c.metric_labels]) == (first.group, first.kind, keys)
            for c in family
        )
        distinct = len({c.metric_labels for c in family}) == len(family)
        if len(family) > 1 and not (alike and keys and distinct):
            raise ValueError(f"metric {name}: shared by counters of another group, kind or labels")


def counters_of(group: Group) -> tuple[CounterSpec, ...]:
    """The group's entries of the table as it is now (read at each call, so a test may extend it)."""
    return _grouped(COUNTERS)[group]


def complete(group: Group, values: Mapping[str, CounterValue]) -> Counts:
    """All the group's figures, in table order, from the measured ``values``; counters with
    ``sum_of`` are (re)computed. Raises KeyError for a declared figure missing from ``values``
    or a value of an undeclared one."""
    specs = counters_of(group)
    declared = {c.name for c in specs}
    extra = set(values) - declared
    if extra:
        raise KeyError(f"not declared in rig.counters ({group}): {', '.join(sorted(extra))}")
    out: Counts = {}
    for c in specs:
        if c.sum_of:
            out[c.name] = sum(_count(values, p, group) for p in c.sum_of)
        elif c.name in values:
            out[c.name] = values[c.name]
        else:
            raise KeyError(f"counter {group}.{c.name} declared in rig.counters but not measured")
    return out


def _count(values: Mapping[str, CounterValue], name: str, group: Group) -> int:
    v = values.get(name)
    if not isinstance(v, int):
        raise KeyError(f"counter {group}.{name} declared in rig.counters but not measured")
    return v


def flatten(snapshot: Any) -> dict[str, Any]:
    """A snapshot dataclass's fields with its ``counters`` side by side, as ``/health`` has them."""
    fields = {f.name: getattr(snapshot, f.name) for f in dataclasses.fields(snapshot) if f.name != "counters"}
    return {**fields, **snapshot.counters}


class Tally:
    """Running values of the group's plain counters (kind ``counter``, no ``sum_of``), all 0 at
    the start. Not thread-safe: the owner counts under its own lock."""

    def __init__(self, group: Group) -> None:
        self.group = group
        self._counts = {c.name: 0 for c in counters_of(group) if c.kind == "counter" and not c.sum_of}

    def add(self, name: str, n: int = 1) -> None:
        """Count ``n`` more of ``name`` (KeyError if the table does not declare it)."""
        if name not in self._counts:
            raise KeyError(f"no counter {self.group}.{name} in rig.counters")
        self._counts[name] += n

    def __getitem__(self, name: str) -> int:
        return self._counts[name]

    def snapshot(self) -> dict[str, CounterValue]:
        return dict(self._counts)


_GROUP_TITLES: dict[Group, str] = {
    "camera": "Camera (`/health` `cameras.<name>.*`; Prometheus label `camera`)",
    "pairing": "Pairing (`/health` `pairing.*`)",
    "worker": "Depth worker (`/health` `worker.*`)",
    "rectification": "Rectification (`/health` `rectification.*`; docs/rectification.md)",
}


def markdown() -> str:
    """``docs/counters.md``: every entry of the table, by group."""
    lines = [
        "# Counters",
        "",
        "<!-- Generated from rig/counters.py by `python -m rig.counters > docs/counters.md`;"
        " a test checks it. -->",
        "",
        "Every figure that `GET /health`, `GET /metrics` and the dashboard show about the cameras,",
        "the stereo pairing, the depth worker and the rectification, declared once in",
        "`rig/counters.py` (also served as JSON by `GET /counters`). A *counter* only grows",
        "(Prometheus adds `_total` to its name);",
        "a *gauge* is a current value. `bool` gauges are `true`/`false` in `/health` and 1/0 in",
        "`/metrics`; gauges that are null in `/health` (nothing measured yet) have no sample.",
        "Not in this table: the worker's per-stage times (`worker.stage_ms`, `rig_stage_latency_ms`",
        "and the `rig_stage_seconds` histogram) and the encode, memory and recording metrics.",
        "",
    ]
    for group in GROUPS:
        lines += [f"## {_GROUP_TITLES[group]}", "", "| name | kind | unit | Prometheus | meaning |"]
        lines.append("|---|---|---|---|---|")
        for c in counters_of(group):
            lines.append(f"| `{c.name}` | {c.kind} | {c.unit} | {_metric_cell(c)} | {_meaning(c)} |")
        lines.append("")
    return "\n".join(lines)


def _metric_cell(c: CounterSpec) -> str:
    scale = f" (× {c.metric_scale:g})" if c.metric_scale != 1.0 else ""
    return f"`{c.metric_selector}`{scale}"


def _meaning(c: CounterSpec) -> str:
    extra = f" Dashboard column *{c.column}*." if c.column else ""
    text = c.help[0].upper() + c.help[1:] + "." + extra
    return text.replace("|", "\\|")  # a bare | would end the table cell


if __name__ == "__main__":
    sys.stdout.write(markdown())
