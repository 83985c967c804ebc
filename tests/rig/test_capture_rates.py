"""Frame-loss rates over a window drive the camera's health: the rule on constructed counters,
and a camera delivering a third of its frames corrupt through FileCamera → supervisor →
StereoCapture (degraded with a named reason, logged once; recovery logged once)."""

from __future__ import annotations

import itertools
import logging
import re
import time
from pathlib import Path
from typing import Any

import pytest

from rig.capture.capture import StereoCapture
from rig.capture.config import SupervisorConfig
from rig.capture.rates import COUNTED, RateLimits, RateWindow
from tests.helpers.recordings import FAST_SUPERVISOR, replay_config, write_recording

LIMITS = RateLimits(window_s=10.0, max_broken_fraction=0.05, max_dropped_fraction=0.1)
ZERO = dict.fromkeys(COUNTED, 0)


def feed(
    window: RateWindow,
    seconds: float,
    fps: float,
    every: dict[str, int],
    start: float = 0.0,
    base: dict[str, int] | None = None,
) -> Any:
    """``seconds`` of a camera at ``fps`` from ``start`` (cumulative counters from ``base``): each
    frame received, except that counter ``k`` takes every ``every[k]``-th frame instead. Returns
    the last assessment."""
    counts = dict(base or ZERO)
    out = None
    n = round(seconds * fps)
    for i in range(1, n + 1):
        hit = next((k for k, m in every.items() if i % m == 0), None)
        if hit in ("frames_corrupt", "frames_lost", "timestamp_errors"):
            counts[hit] += 1
        else:
            counts["frames_received"] += 1
            if hit is not None:
                counts[hit] += 1
        out = window.observe(round((start + i / fps) * 1e9), counts)
    _last[window] = counts
    return out


_last: dict[RateWindow, dict[str, int]] = {}


def last_counts(window: RateWindow) -> dict[str, int]:
    """The cumulative counters :func:`feed` left ``window`` at."""
    return dict(_last[window])


def test_a_third_corrupt_is_named_with_its_share_and_window() -> None:
    a = feed(RateWindow(LIMITS), 12.0, 30.0, {"frames_corrupt": 3})
    assert a.kind == "broken" and a.problem == "33 % of frames corrupt over the last 10 s"
    assert a.corrupt_per_s == pytest.approx(10.0, rel=0.05) and a.dropped_per_s == 0.0


def test_undecodable_frames_count_as_broken() -> None:
    a = feed(RateWindow(LIMITS), 12.0, 30.0, {"frames_undecodable": 10})
    assert a.problem == "10 % of frames undecodable over the last 10 s"
    assert a.undecodable_per_s == pytest.approx(3.0, rel=0.05)


def test_dropped_frames_name_where_they_went() -> None:
    lost = feed(RateWindow(LIMITS), 12.0, 30.0, {"frames_lost": 2})
    assert lost.kind == "dropped" and lost.problem == (
        "50 % of frames dropped (lost by the camera or driver) over the last 10 s"
    )
    unpaired = feed(RateWindow(LIMITS), 12.0, 30.0, {"frames_unpaired": 4})
    assert unpaired.problem == "25 % of frames dropped (without a partner frame) over the last 10 s"


def test_within_limits_and_too_early_say_nothing() -> None:
    fine = feed(RateWindow(LIMITS), 12.0, 30.0, {"frames_corrupt": 25, "frames_lost": 15})  # 4 %, 6.7 %
    assert fine.problem is None and fine.corrupt_per_s is not None
    early = feed(RateWindow(LIMITS), 0.5, 30.0, {"frames_corrupt": 2})
    assert early.problem is None and early.corrupt_per_s is None, "under a second: not judged yet"
    # Shorter than the window so far: the span it covers is named.
    partial = feed(RateWindow(LIMITS), 4.0, 30.0, {"frames_corrupt": 2})
    assert partial.problem == "50 % of frames corrupt over 4 s"


def test_the_window_forgets_what_is_older_and_restarted_counters_start_over() -> None:
    window = RateWindow(LIMITS)
    feed(window, 5.0, 30.0, {"frames_corrupt": 2})
    counts = {**ZERO, "frames_received": 75, "frames_corrupt": 75}
    # 20 s of clean frames after that: the corrupt ones fell out of the window.
    for i in range(1, 601):
        counts["frames_received"] += 1
        a = window.observe(round((5.0 + i / 30.0) * 1e9), counts)
    assert a.problem is None and a.corrupt_per_s == 0.0
    restarted = window.observe(round(26e9), dict(ZERO))
    assert restarted.corrupt_per_s is None


def test_limits_come_from_the_supervisor_settings() -> None:
    sup = SupervisorConfig()
    assert (sup.rate_window_s, sup.max_broken_fraction, sup.max_dropped_fraction) == (10.0, 0.05, 0.1)
    with pytest.raises(ValueError, match="max_broken_fraction"):
        SupervisorConfig(max_broken_fraction=1.5)


def test_a_camera_with_a_third_of_its_frames_corrupt_is_degraded_then_recovers(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # Before: it stayed "available" with no reason at all. 20 fps; frames 2, 5, 8, ... of the
    # first 45 (2.25 s) corrupt; a 1 s window; a lenient watchdog (the test machine is shared).
    rec = write_recording(tmp_path / "rec", 30)
    corrupt = tuple({"kind": "corrupt", "count": 1, "at_frame": k} for k in range(2, 47, 3))
    supervisor = FAST_SUPERVISOR.model_copy(update={"rate_window_s": 1.0, "watchdog_s": 2.0})
    config = replay_config(rec, pace=20.0, loop=True, left_faults=corrupt, supervisor=supervisor)
    seen: list[str | None] = []
    with caplog.at_level(logging.INFO, logger="rig.capture"), StereoCapture(config) as cap:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            cap.next_pair(0.05)
            left = cap.health().cameras["left"]
            seen.append(left.degraded_reason)
            if left.counters["frames_received"] > 90 and left.degraded_reason is None and any(seen):
                break
        last = cap.health().cameras["left"]
    corrupt_reasons = [r for r in seen if r and "corrupt" in r]
    assert corrupt_reasons, f"never degraded by the corrupt frames: {set(seen)}"
    shares = {
        int(m.group(1)) for r in corrupt_reasons if (m := re.fullmatch(r"(\d+) % of frames corrupt .*", r))
    }
    assert max(shares) in range(28, 40), corrupt_reasons
    assert any(r.endswith("over the last 1 s") for r in corrupt_reasons)
    assert last.degraded_reason is None and last.connected, "recovered once the corruption stopped"
    messages = [r.getMessage() for r in caplog.records if r.name == "rig.capture"]
    said = [m for m in messages if m.startswith("camera left degraded: ") and "corrupt" in m]
    assert len(said) == 1, messages
    # Each episode is logged once when it starts and once when it is over (frames a starved
    # camera thread skips on a loaded machine may make another, of dropped frames).
    episodes = [
        m.split(":")[0] for m in messages if m.startswith(("camera left degraded", "camera left recovered"))
    ]
    assert episodes[0] == "camera left degraded" and episodes[-1] == "camera left recovered", messages
    assert all(a != b for a, b in itertools.pairwise(episodes) if a == "camera left recovered"), messages


def test_a_share_at_the_limit_does_not_flap() -> None:
    """Once degraded, a problem lasts until its share is below half its limit."""
    window = RateWindow(LIMITS)
    a = feed(window, 11.0, 30.0, {"frames_corrupt": 10})  # 10 %: degraded
    assert a.kind == "broken"
    b = feed(window, 11.0, 30.0, {"frames_corrupt": 25}, start=11.0, base=last_counts(window))  # 4 %
    assert b.kind == "broken" and b.problem.startswith("4 % of frames corrupt")
    c = feed(window, 11.0, 30.0, {"frames_corrupt": 50}, start=22.0, base=last_counts(window))  # 2 %
    assert c.kind is None and c.problem is None
    d = feed(window, 11.0, 30.0, {"frames_corrupt": 25}, start=33.0, base=last_counts(window))  # 4 %
    assert d.kind is None, "not degraded again below the limit itself"
