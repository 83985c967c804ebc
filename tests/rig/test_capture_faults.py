"""Every injected fault through FileCamera → supervisor → StereoCapture: state, reason, and
counters that match exactly what the file camera says it did."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from rig.capture.capture import StereoCapture
from rig.capture.config import CaptureConfig, PairingConfig, V4L2CameraConfig
from rig.capture.faults import DisconnectFault
from rig.capture.file_camera import FileCamera
from rig.capture.health import CameraHealth, CaptureHealth
from rig.capture.v4l2 import V4L2Camera
from rig.errors import ConfigError
from tests.helpers.recordings import replay_config, write_recording

FPS = 50.0
PERIOD_S = 1 / FPS


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_recording(tmp_path_factory.mktemp("faults") / "rec", 30)


def run_until(
    cap: StereoCapture, pred: Callable[[CaptureHealth], bool], timeout_s: float = 15.0
) -> CaptureHealth:
    end = time.monotonic() + timeout_s
    while True:
        cap.next_pair(0.05)  # a consumer taking the newest pair, like the service worker
        h = cap.health()
        if pred(h):
            return h
        if time.monotonic() > end:
            raise AssertionError(f"condition not reached: {json.dumps(h.as_dict(), default=str)[:2000]}")


def stats(cap: StereoCapture, name: str) -> Any:
    cam = cap.camera(name)
    assert isinstance(cam, FileCamera)
    return cam.stats()


def dropped_by_pairing(c: CameraHealth) -> int:
    return c.counters["frames_unpaired"] + c.counters["frames_evicted"]


def capture(rec: Path, **kw: Any) -> StereoCapture:
    return StereoCapture(replay_config(rec, pace=FPS, loop=True, **kw))


def steady(h: CaptureHealth, n: int = 60) -> bool:
    return all(c.connected and c.counters["frames_received"] >= n for c in h.cameras.values())


@pytest.mark.parametrize("kind,check", [("corrupt", "JPEG header damaged"), ("truncate", "JPEG truncated")])
def test_corrupt_and_truncated_frames_are_counted_exactly(rec: Path, kind: str, check: str) -> None:
    with capture(rec, left_faults=({"kind": kind, "at_frame": 10, "count": 3},)) as cap:
        run_until(cap, steady)
    h = cap.health()  # stopped: every counter is final
    left, right = h.cameras["left"], h.cameras["right"]
    assert (
        left.counters["frames_corrupt"]
        == 3
        == getattr(stats(cap, "left"), "corrupted" if kind == "corrupt" else "truncated")
    )
    assert check in (left.last_error or "") and left.state == "stopped"
    # Their partners had nothing to pair with: dropped and counted, nothing else lost.
    assert dropped_by_pairing(right) == 3 and right.counters["frames_dropped"] == 3
    assert (
        left.counters["frames_dropped"],
        left.counters["frames_lost"],
        right.counters["frames_lost"],
        right.counters["frames_corrupt"],
    ) == (0, 0, 0, 0)


def test_stall_is_reported_and_recovers_with_exact_losses(rec: Path) -> None:
    duration = 0.71  # 35.5 periods at 50 fps
    with capture(rec, left_faults=({"kind": "stall", "at_frame": 10, "duration_s": duration},)) as cap:
        h = run_until(cap, lambda h: h.cameras["left"].state == "unavailable")
        assert h.cameras["left"].reason == "no frame for more than 0.30 s"
        assert h.cameras["right"].connected
        run_until(cap, lambda h: steady(h) and h.cameras["left"].counters["frames_received"] >= 40)
    h = cap.health()
    left, right = h.cameras["left"], h.cameras["right"]
    expected = math.ceil(duration * FPS)
    assert left.counters["frames_lost"] == expected == stats(cap, "left").lost
    assert dropped_by_pairing(right) == expected and dropped_by_pairing(left) == 0
    assert left.counters["frames_dropped"] == expected and right.counters["frames_dropped"] == expected


def test_disconnect_reconnects_with_exact_losses(rec: Path) -> None:
    with capture(rec, right_faults=({"kind": "disconnect", "at_frame": 10, "duration_s": 0.31},)) as cap:
        h = run_until(cap, lambda h: h.cameras["right"].state == "unavailable")
        assert "disconnected (injected fault)" in (h.cameras["right"].reason or "")
        run_until(cap, lambda h: steady(h) and h.cameras["right"].counters["reconnects"] == 1)
    h = cap.health()
    left, right = h.cameras["left"], h.cameras["right"]
    s = stats(cap, "right")
    assert right.counters["frames_lost"] == s.lost >= math.ceil(0.31 * FPS)
    assert s.disconnects == 1 and right.counters["reconnect_attempts"] >= 1
    assert dropped_by_pairing(left) == right.counters["frames_lost"] and dropped_by_pairing(right) == 0


@pytest.mark.parametrize("offset_ms,words", [(2000.0, "ahead of"), (-2000.0, "behind")])
def test_timestamp_jump_is_rejected_and_recovered_by_reconnect(
    rec: Path, offset_ms: float, words: str
) -> None:
    fault = {"kind": "timestamp_jump", "at_frame": 10, "offset_ms": offset_ms}
    with capture(rec, right_faults=(fault,)) as cap:
        h = run_until(cap, lambda h: h.cameras["right"].counters["timestamp_errors"] >= 1)
        assert words in (h.cameras["right"].last_error or "")
        run_until(cap, lambda h: steady(h) and h.cameras["right"].counters["reconnects"] == 1)
    h = cap.health()
    left, right = h.cameras["left"], h.cameras["right"]
    assert right.counters["timestamp_errors"] == 1  # the reconnect re-validated the clock at once
    # The rejected frame's partner, plus anything the reconnect skipped, went unpaired.
    assert dropped_by_pairing(left) == 1 + right.counters["frames_lost"]
    assert right.counters["frames_lost"] == stats(cap, "right").lost


def test_half_rate_camera(rec: Path) -> None:
    with capture(rec, right_faults=({"kind": "rate", "at_frame": 10, "factor": 0.5, "frames": 20},)) as cap:
        run_until(cap, steady)
    h = cap.health()  # stopped: every counter is final
    left, right = h.cameras["left"], h.cameras["right"]
    assert right.counters["frames_lost"] == 10 == stats(cap, "right").lost
    assert "1 frame(s) lost before seq" in (right.last_error or "")
    assert dropped_by_pairing(left) == 10 and dropped_by_pairing(right) == 0


def test_drop_fault(rec: Path) -> None:
    with capture(rec, left_faults=({"kind": "drop", "at_frame": 5, "count": 4},)) as cap:
        run_until(cap, steady)
    h = cap.health()
    assert h.cameras["left"].counters["frames_lost"] == 4 and dropped_by_pairing(h.cameras["right"]) == 4


def test_runtime_injection_shows_in_health_and_clears(rec: Path) -> None:
    with capture(rec) as cap:
        run_until(cap, lambda h: steady(h, 10))
        cap.inject("left", DisconnectFault(duration_s=0.4))
        h = run_until(cap, lambda h: not h.cameras["left"].connected, timeout_s=1.0)
        assert "disconnected" in (h.cameras["left"].reason or "")
        h = run_until(
            cap, lambda h: h.cameras["left"].connected and h.cameras["left"].counters["reconnects"] == 1
        )
        taken = h.pairing.counters["pairs_taken"]
        run_until(cap, lambda h: h.pairing.counters["pairs_taken"] > taken + 5)  # depth would resume


def test_pair_hand_out_and_health_document(rec: Path) -> None:
    with capture(rec) as cap:
        run_until(cap, lambda h: steady(h, 5))
        time.sleep(4 * PERIOD_S)
        newest = cap.next_pair(1.0)
        assert newest is not None and newest.left.seq == newest.right.seq
        assert abs(newest.skew_ns) <= cap.skew_gate_ns
        oldest = cap.next_pair(1.0, newest=False)
        assert oldest is not None and oldest.seq > newest.seq
        h = cap.health()
    p = h.pairing
    parts = ("pairs_taken", "pairs_skipped", "pairs_evicted", "pairs_pending")
    assert p.counters["pairs_formed"] == sum(p.counters[k] for k in parts)  # type: ignore[misc]
    assert p.counters["skew_ms"] == 0.0 and p.skew_gate_ms == pytest.approx(10.0)
    doc = json.loads(json.dumps(h.as_dict()))
    assert set(doc["cameras"]["left"]) >= {"connected", "fps", "frames_dropped", "last_frame_age_ms"}
    assert doc["cameras"]["left"]["timestamp_source"] == "live"
    assert 30 < doc["cameras"]["left"]["fps"] < 70  # measured from arrivals


def test_replay_without_loop_finishes(rec: Path) -> None:
    cfg = replay_config(rec, pace="fast", timestamps="recorded", pairing=PairingConfig(backpressure=True))
    with StereoCapture(cfg) as cap:
        seqs = []
        while (p := cap.next_pair(2.0, newest=False)) is not None:
            seqs.append(p.seq)
        assert cap.exhausted
        assert seqs == list(range(30))
        assert {c.state for c in cap.health().cameras.values()} == {"ended"}


def test_fault_injection_needs_a_camera_that_supports_it(rec: Path) -> None:
    cfg = CaptureConfig.model_validate(
        {"left": {"kind": "v4l2", "device": 0}, "right": {"kind": "v4l2", "device": 1}}
    )
    cams = {n: V4L2Camera(cfg.camera(n), n) for n in ("left", "right")}  # type: ignore[arg-type]
    assert isinstance(cfg.left, V4L2CameraConfig)
    cap = StereoCapture(cfg, cameras=cams)
    with pytest.raises(ConfigError, match=r"camera left \(v4l2\) does not support fault injection"):
        cap.inject("left", DisconnectFault(duration_s=1))
    with pytest.raises(ConfigError, match="unknown camera"):
        cap.camera("middle")
    cap.stop()  # never started: still fine


def test_backpressure_replay_hands_out_every_pair_to_a_slow_consumer(tmp_path: Path) -> None:
    src = write_recording(tmp_path / "rec", 40, seqs=[k for k in range(40) if k % 7 != 3])
    pairing = PairingConfig(backpressure=True, pair_buffer=1, buffer_size=1)
    expected = [k for k in range(40) if k % 7 != 3]
    for round_ in range(3):
        cfg = replay_config(src, pace="fast", timestamps="recorded", pairing=pairing)
        with StereoCapture(cfg) as cap:
            seqs = []
            while (p := cap.next_pair(5.0, newest=False)) is not None:
                seqs.append(p.seq)
                if len(seqs) % (3 + round_) == 0:
                    time.sleep(0.01)  # a consumer that sometimes falls behind
        assert seqs == expected
        h = cap.health()
        assert h.pairing.counters["pairs_evicted"] == 0 and h.cameras["left"].counters["frames_evicted"] == 0
