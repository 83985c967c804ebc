"""Depth that stops coming is a verdict, not a silent "ok": cameras swapped mid-stream make the
service degraded with the figures and the likely cause, and it recovers when they are back; a
stereo change that breaks the matcher on the scene is refused with the figures. In process (the
app in process, tests.helpers.service.in_process); the swapped stream is a recording whose later rows exchange
the two cameras' files, replayed in a loop."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import pytest

from rig.depth_watch import DepthWatch, SettingsTrial
from service.settings import load_settings
from tests.helpers.service import AUTH, SmallRecording, in_process, service_overrides
from tests.helpers.waiting import wait_for

pytestmark = pytest.mark.timeout(180)


def _swapping_recording(source: Path, out: Path, normal: int, swapped: int) -> Path:
    """``source``'s pairs cycled for ``normal`` rows, then ``swapped`` rows with the left and right
    files exchanged (a camera plugged into the other port mid-stream)."""
    shutil.copytree(source, out)
    with (source / "frames.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    period = int(rows[1]["left_ts_ns"]) - int(rows[0]["left_ts_ns"])
    t0 = int(rows[0]["left_ts_ns"])
    with (out / "frames.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["seq", "left_ts_ns", "right_ts_ns", "left_file", "right_file"])
        for i in range(normal + swapped):
            row = rows[i % len(rows)]
            files = [row["left_file"], row["right_file"]]
            if i >= normal:
                files.reverse()
            w.writerow([i, t0 + i * period, t0 + i * period, *files])
    return out


def test_the_watch_judges_the_recent_median_against_the_reference() -> None:
    watch = DepthWatch(recent_s=2.0, reference_s=4.0, min_frames=3)
    for k in range(40):
        watch.observe(k * 0.1, 0.5, 1)
    assert watch.verdict(4.0) is None
    for k in range(40, 70):
        watch.observe(k * 0.1, 0.03, 2)
    verdict = watch.verdict(7.0)
    assert verdict is not None and "from 50 % to 3 %" in verdict and "revision 2" in verdict
    # It holds for as long as the collapse lasts, long after both windows hold only poor frames.
    for k in range(70, 140):
        watch.observe(k * 0.1, 0.03, 2)
    assert watch.verdict(14.0) == verdict
    # Back to 70 % of the coverage before the collapse: recovered.
    for k in range(140, 170):
        watch.observe(k * 0.1, 0.4, 2)
    assert watch.verdict(17.0) is None
    # A scene poor from the start has nothing to fall from.
    poor = DepthWatch(recent_s=2.0, reference_s=4.0, min_frames=3)
    for k in range(70):
        poor.observe(k * 0.1, 0.03, 1)
    assert poor.verdict(7.0) is None


def test_a_trial_says_when_new_settings_collapse() -> None:
    assert SettingsTrial(0.6, 0.55, 0.95).collapse() is None
    assert "give depth on 10 %" in (SettingsTrial(0.6, 0.1, 0.9).collapse() or "")
    assert "agree with the parameters in effect on 20 %" in (SettingsTrial(0.6, 0.6, 0.2).collapse() or "")
    assert SettingsTrial(0.01, 0.0, 0.0).collapse() is None  # nothing to compare with


def test_swapped_cameras_mid_stream_are_a_verdict_and_recovery_is_seen(
    small_recording: SmallRecording, lut_cache: Path, tmp_path: Path
) -> None:
    rec = _swapping_recording(small_recording.loop, tmp_path / "swapping", normal=60, swapped=60)
    doc = service_overrides(rec, tmp_path, lut_cache)
    doc["depth_watch"] = {"recent_s": 1.5, "reference_s": 3.0}
    with in_process(load_settings(None, doc)) as server:
        client, app = server.client, server.app
        wait_for(lambda: client.get("/depth").status_code == 200, 60, "a depth frame")

        def degraded() -> list[str] | None:
            h = client.get("/health").json()
            said = [r for r in h["reasons"] if r.startswith("depth: valid depth fell from")]
            return said if h["status"] == "degraded" and said else None

        said = wait_for(degraded, 40, "the collapse of valid depth in /health")
        runtime = app.state.runtime
        wait_for(lambda: runtime.collapse_check is not None, 30, "the likely cause")
        reason = wait_for(
            lambda: next((r for r in client.get("/health").json()["reasons"] if "likely cause" in r), None),
            30,
            "the likely cause in /health",
        )
        print(f"\n{said[0]}\n{reason}")
        assert "swapped" in reason
        # The loop brings the right order back: the verdict goes away.
        wait_for(lambda: runtime.depth_collapse() is None, 40, "the recovery")


def test_a_change_that_breaks_the_matcher_on_the_scene_is_refused(
    small_recording: SmallRecording, lut_cache: Path, tmp_path: Path
) -> None:
    """Inside every field's bounds, and no 16-bit overflow: a search that starts beyond every
    disparity of the scene gives depth on almost nothing (and none of it right)."""
    with in_process(
        load_settings(None, service_overrides(small_recording.loop, tmp_path, lut_cache))
    ) as server:
        client = server.client
        wait_for(lambda: client.get("/depth").status_code == 200, 60, "a depth frame")
        before = client.get("/config").json()
        r = client.patch(
            "/config", json={"stereo": {"min_disparity": 80, "disparity_range": 32}}, headers=AUTH
        )
        assert r.status_code == 422, r.text
        detail = r.json()["detail"]
        assert detail.startswith("stereo parameters refused: on the newest frame they give depth on")
        after = client.get("/config").json()
        assert after["revision"] == before["revision"] and after["stereo"] == before["stereo"]
        # A change the scene supports goes through.
        ok = client.patch("/config", json={"stereo": {"correlation_window_size": 9}}, headers=AUTH)
        assert ok.status_code == 200, ok.text
