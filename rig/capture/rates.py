"""Frame-loss rates of one camera over a sliding window, and the health rule they drive.

A camera that delivers a third of its frames corrupt is still *available* (frames arrive), yet
the depth it feeds is a third of what it should be: the service must say so. A
:class:`RateWindow` keeps samples of the camera's cumulative counters (at most one per
``SAMPLE_S``) over the last ``cameras.supervisor.rate_window_s`` and turns their differences into
per-second rates and fractions of the frames that arrived:

* *broken* = (corrupt + undecodable) / arrived, against ``max_broken_fraction``;
* *dropped* = dropped / (arrived + lost), against ``max_dropped_fraction`` (``dropped`` = lost +
  unpaired + evicted, the counter table's ``frames_dropped``; a lost frame never arrived).

``arrived`` = received + corrupt + timestamp errors: every frame the camera handed over. Above a
threshold the assessment names the problem ("33 % of frames corrupt over the last 10 s"); a
problem lasts until its share falls below half its threshold (so a share hovering at the limit
does not flap), and the capture logs it once when it starts and once when it is over.
Nothing is judged until the window holds ``MIN_FRAMES`` frames over at least ``MIN_SPAN_S``.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["COUNTED", "MIN_FRAMES", "MIN_SPAN_S", "SAMPLE_S", "RateAssessment", "RateLimits", "RateWindow"]

#: Shortest time between two samples (seconds): bounds the window's memory.
SAMPLE_S = 0.1
#: Frames (arrived + lost) and seconds a window must cover before it is judged.
MIN_FRAMES = 10
MIN_SPAN_S = 1.0

#: The camera counters (rig.counters) the rates are made of.
COUNTED = (
    "frames_received",
    "frames_corrupt",
    "frames_undecodable",
    "timestamp_errors",
    "frames_lost",
    "frames_unpaired",
    "frames_evicted",
)


@dataclass(frozen=True)
class RateLimits:
    """The thresholds (fractions in [0, 1]) and the window (s) of the health rule."""

    window_s: float
    max_broken_fraction: float
    max_dropped_fraction: float


@dataclass(frozen=True)
class RateAssessment:
    """Rates over the window: per second (None until judged) and the problem, if any."""

    corrupt_per_s: float | None
    undecodable_per_s: float | None
    dropped_per_s: float | None
    problem: str | None = None
    kind: str | None = None  # "broken" or "dropped": what the problem is about


_UNJUDGED = RateAssessment(None, None, None)


def _percent(fraction: float) -> str:
    return f"{100.0 * fraction:.0f} %"


def _broken_words(corrupt: int, undecodable: int) -> str:
    if not undecodable:
        return "corrupt"
    return "undecodable" if not corrupt else "corrupt or undecodable"


def _dropped_words(d: Mapping[str, int]) -> str:
    """Where most of the dropped frames went, in words a technician can act on."""
    causes = {
        "lost by the camera or driver": d["frames_lost"],
        "without a partner frame": d["frames_unpaired"],
        "pushed out of a full buffer": d["frames_evicted"],
    }
    return max(causes, key=lambda k: causes[k])


class RateWindow:
    """Samples of one camera's counters and the rates over the window (thread-safe)."""

    def __init__(self, limits: RateLimits) -> None:
        self.limits = limits
        self._lock = threading.Lock()
        self._samples: deque[tuple[int, dict[str, int]]] = deque()
        self._kind: str | None = None  # the problem being reported (under _lock)

    def observe(self, now_ns: int, counters: Mapping[str, object]) -> RateAssessment:
        """Add a sample of the cumulative ``counters`` (a camera snapshot's) taken at
        ``now_ns`` and assess the window ending there."""
        sample = {k: int(counters[k]) for k in COUNTED}  # type: ignore[call-overload]
        window_ns = round(self.limits.window_s * 1e9)
        with self._lock:
            if not self._samples or now_ns - self._samples[-1][0] >= SAMPLE_S * 1e9:
                self._samples.append((now_ns, sample))
            # Keep one sample at or before the window's start, so the window is covered whole.
            while len(self._samples) > 2 and now_ns - self._samples[1][0] >= window_ns:
                self._samples.popleft()
            t0, first = self._samples[0]
        span_s = (now_ns - t0) / 1e9
        d = {k: sample[k] - first[k] for k in COUNTED}
        if any(v < 0 for v in d.values()):  # counters restarted (a new capture): start over
            with self._lock:
                self._samples.clear()
                self._samples.append((now_ns, sample))
                self._kind = None
            return _UNJUDGED
        with self._lock:
            out = self._assess(d, span_s, self._kind)
            if out.corrupt_per_s is not None:
                self._kind = out.kind
            return out

    def _assess(self, d: Mapping[str, int], span_s: float, current: str | None) -> RateAssessment:
        arrived = d["frames_received"] + d["frames_corrupt"] + d["timestamp_errors"]
        dropped = d["frames_lost"] + d["frames_unpaired"] + d["frames_evicted"]
        if span_s < MIN_SPAN_S or arrived + d["frames_lost"] < MIN_FRAMES:
            return _UNJUDGED
        rates = (d["frames_corrupt"] / span_s, d["frames_undecodable"] / span_s, dropped / span_s)
        lim = self.limits
        over = (
            f"over the last {lim.window_s:g} s" if span_s >= lim.window_s * 0.99 else f"over {span_s:.0f} s"
        )

        def limit(kind: str, threshold: float) -> float:
            return threshold / 2 if current == kind else threshold  # hysteresis (module doc)

        broken = (d["frames_corrupt"] + d["frames_undecodable"]) / max(1, arrived)
        if broken > limit("broken", lim.max_broken_fraction):
            words = _broken_words(d["frames_corrupt"], d["frames_undecodable"])
            return RateAssessment(*rates, f"{_percent(broken)} of frames {words} {over}", "broken")
        lost_share = dropped / max(1, arrived + d["frames_lost"])
        if lost_share > limit("dropped", lim.max_dropped_fraction):
            text = f"{_percent(lost_share)} of frames dropped ({_dropped_words(d)}) {over}"
            return RateAssessment(*rates, text, "dropped")
        return RateAssessment(*rates)

    def reset(self) -> None:
        with self._lock:
            self._samples.clear()
            self._kind = None
