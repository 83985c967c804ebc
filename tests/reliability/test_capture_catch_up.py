"""A paced file camera whose reading thread was starved of CPU catches up instead of handing out
stale frames (which the supervisor rejects as a clock jump and reconnects, so the camera flapped
to unavailable on a loaded 2-core machine). Deterministic: the camera runs on a fake clock."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.capture.config import SupervisorConfig
from rig.capture.file_camera import FileCamera
from rig.capture.protocol import TimeBase
from tests.helpers.recordings import file_camera_config, write_recording

FPS = 10.0
PERIOD_NS = 100_000_000


class FakeClock:
    def __init__(self, t_ns: int) -> None:
        self.t_ns = t_ns

    def __call__(self) -> int:
        return self.t_ns


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_recording(tmp_path_factory.mktemp("catch-up") / "rec", 12)


def camera(rec: Path, clock: FakeClock) -> FileCamera:
    cfg = file_camera_config(rec, "left", pace=FPS, loop=True, timestamps="live")
    return FileCamera(cfg, "left", clock=clock, timebase=TimeBase(clock))


@pytest.mark.parametrize("starved_ms", [260, 1000, 5000])
def test_a_starved_reader_skips_stale_frames_and_counts_them(rec: Path, starved_ms: int) -> None:
    clock = FakeClock(10**12)
    cam = camera(rec, clock)
    cam.open()
    first = cam.read(0.0)
    assert first is not None and first.seq == 0 and first.ts_ns == 10**12
    clock.t_ns += starved_ms * 1_000_000  # the thread did not run for this long
    frame = cam.read(0.0)
    assert frame is not None
    catch_up_ns = round(FileCamera.CATCH_UP_S * 1e9)
    # Frames k = 1, 2, ... are due at k periods; those due before now - CATCH_UP_S are lost.
    now = clock.t_ns
    expected_seq = next(k for k in range(1, 1000) if 10**12 + k * PERIOD_NS >= now - catch_up_ns)
    assert frame.seq == expected_seq and frame.ts_ns == 10**12 + expected_seq * PERIOD_NS
    age_ns = frame.host_ns - frame.ts_ns
    assert 0 <= age_ns <= catch_up_ns < SupervisorConfig().max_clock_offset_ms * 1e6
    s = cam.stats()
    assert s.lost == s.lost_late == expected_seq - 1 and s.delivered == 2
    # Then it is on schedule again: the next frame comes one period later, nothing else lost.
    clock.t_ns = frame.ts_ns + PERIOD_NS
    nxt = cam.read(0.0)
    assert nxt is not None and nxt.seq == expected_seq + 1 and cam.stats().lost == expected_seq - 1


def test_a_reader_on_time_loses_nothing(rec: Path) -> None:
    clock = FakeClock(10**12)
    cam = camera(rec, clock)
    cam.open()
    for k in range(30):  # across two loops of the 12-pair recording
        clock.t_ns = 10**12 + k * PERIOD_NS + 240_000_000  # always 240 ms late: within catch-up
        f = cam.read(0.0)
        assert f is not None and f.seq == k
    assert cam.stats().lost == 0 and cam.stats().lost_late == 0


def test_outage_losses_are_not_counted_as_late(rec: Path) -> None:
    clock = FakeClock(10**12)
    cam = camera(rec, clock)
    cam.open()
    assert cam.read(0.0) is not None
    cam.inject({"kind": "stall", "duration_s": 0.5})  # from frame 1's due time: frames 1..5
    clock.t_ns = 10**12 + 6 * PERIOD_NS
    f = cam.read(0.0)
    assert f is not None and f.seq == 6
    assert cam.stats().lost == 5 and cam.stats().lost_late == 0


@pytest.mark.parametrize("kind", ["stall", "disconnect"])
@pytest.mark.parametrize("reader_late_ms", [0, 50, 200])
def test_an_outage_loses_the_same_frames_however_late_the_reader(
    rec: Path, kind: str, reader_late_ms: int
) -> None:
    clock = FakeClock(10**12)
    cam = camera(rec, clock)
    cam.open()
    assert cam.read(0.0) is not None
    # Frame 1 is due at +100 ms; the reader has not picked it up yet when the fault comes.
    clock.t_ns = 10**12 + PERIOD_NS + reader_late_ms * 1_000_000
    cam.inject({"kind": kind, "duration_s": 1.5})  # from frame 1's due time: frames 1..15
    clock.t_ns = 10**12 + 17 * PERIOD_NS  # the outage is over: frame 16 is due 100 ms ago
    if kind == "disconnect":
        cam.close()
        cam.open()
    f = cam.read(0.0)
    assert f is not None and f.seq == 16
    assert cam.stats().lost == 15 and cam.stats().lost_late == 0
