"""Synchronised sets of N cameras (rig.capture.pairing, rig.capture.capture.RigCapture,
rig.capture.recorder): the pair's rules over N heads, every set of a replayed N-camera recording
delivered in order and re-recorded byte for byte."""

from __future__ import annotations

import filecmp
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.capture.capture import RigCapture
from rig.capture.config import CaptureConfig
from rig.capture.frame import Frame, FramePair, FrameSet
from rig.capture.pairing import FramePairer
from rig.capture.recorder import Recorder, replay_capture_config
from rig.errors import ConfigError, RecordingError
from rig.recording import Recording, RecordingWriter
from tests.helpers.recordings import write_set_recording

PERIOD = 33_333_333
GATE = PERIOD // 2
CAMS = ("cam1", "cam2", "cam3")


def frame(cam: str, seq: int, ts: int) -> Frame:
    return Frame(cam, seq, ts, "jpeg", host_ns=0, raw=b"\xff\xd8\xff\xd9")


def streams(seqs: dict[str, list[int]], jitter: dict[tuple[str, int], int]) -> dict[str, list[Frame]]:
    return {
        c: [frame(c, k, 10**9 + k * PERIOD + jitter.get((c, k), 0)) for k in ks] for c, ks in seqs.items()
    }


def push_all(pairer: FramePairer, order: list[Frame]) -> list[FrameSet]:
    out: list[FrameSet] = []
    for f in order:
        out += pairer.push(f)
    return out


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), drop=st.floats(0.0, 0.3))
def test_sets_are_the_frames_every_camera_has_whatever_the_arrival_order(seed: int, drop: float) -> None:
    rng = np.random.default_rng(seed)
    n = 60
    seqs = {c: [k for k in range(n) if rng.random() >= drop] for c in CAMS}
    jitter = {(c, k): int(rng.uniform(-6e6, 6e6)) for c in CAMS for k in range(n)}
    per_camera = streams(seqs, jitter)
    order = sorted((f for fs in per_camera.values() for f in fs), key=lambda f: rng.random())
    # Each camera's frames arrive in its own order (a camera delivers in time order).
    queues = {c: list(fs) for c, fs in per_camera.items()}
    arrival = [queues[f.camera].pop(0) for f in order]
    pairer = FramePairer(GATE, buffer_size=n, skew_window=n, names=CAMS)
    sets = push_all(pairer, arrival)
    everyone = sorted(set.intersection(*(set(v) for v in seqs.values())))
    got = [[f.seq for f in s.frames] for s in sets]
    # Every seq all three cameras have forms a set, except the last ones still waiting.
    assert got == [[k, k, k] for k in everyone[: len(got)]]
    assert len(everyone) - len(got) <= 1
    assert all(s.spread_ns <= GATE and s.cameras == list(CAMS) for s in sets)
    c = pairer.counts()
    for cam in CAMS:
        assert c.unpaired[cam] + c.buffered[cam] + len(sets) == len(seqs[cam]), cam


def test_never_a_set_across_a_gap_and_two_cameras_are_pairs() -> None:
    per_camera = streams({"cam1": [0, 1, 4], "cam2": [0, 1, 2, 3, 4], "cam3": [0, 2, 4]}, {})
    pairer = FramePairer(GATE, names=CAMS)
    sets = push_all(pairer, [f for fs in per_camera.values() for f in fs])
    assert [s.seq for s in sets] == [0, 4]
    assert pairer.counts().unpaired == {"cam1": 1, "cam2": 3, "cam3": 1}
    two = push_all(FramePairer(GATE, names=("a", "b")), [frame("a", 0, 0), frame("b", 0, 5)])
    assert isinstance(two[0], FramePair) and two[0].skew_ns == -5
    with pytest.raises(ValueError, match="two or more different cameras"):
        FramePairer(GATE, names=("a", "a"))


def test_a_replayed_ring_delivers_every_set_and_re_records_byte_for_byte(tmp_path: Path) -> None:
    source = write_set_recording(
        tmp_path / "ring", ("cam1", "cam2", "cam3", "cam4"), 8, skews_ns=(0, 3, 1, 2)
    )
    config, rec = replay_capture_config(source)
    assert config.names == ["cam1", "cam2", "cam3", "cam4"] and config.left is None
    with RigCapture(config) as capture:
        recorder = Recorder(capture, lambda: RecordingWriter(tmp_path / "copy", cameras=config.names))
        result = recorder.run(max_seconds=60)
        with pytest.raises(ConfigError, match="delivers sets, not pairs"):
            capture.next_pair(0.01)
        health = capture.health()
    recorder.complete()
    assert result.pairs_written == 8 and result.stopped_by == "end of recording"
    assert sorted(health.cameras) == ["cam1", "cam2", "cam3", "cam4"]
    assert health.pairing.counters["pairs_formed"] == 8
    assert (tmp_path / "copy" / "frames.csv").read_bytes() == (source / "frames.csv").read_bytes()
    for row in Recording(tmp_path / "copy").pairs:
        for cam in row.cameras:
            assert filecmp.cmp(tmp_path / "copy" / row.file(cam), source / row.file(cam), shallow=False)
    assert rec.cameras == config.names


def test_a_capture_config_names_two_cameras_or_a_rig() -> None:
    cam = {"kind": "file", "recording": "r", "camera": "x"}
    rig = CaptureConfig.model_validate({"rig": {"a": cam, "b": cam, "c": cam}})
    assert rig.names == ["a", "b", "c"] and rig.camera("c").recording == Path("r")
    with pytest.raises(ConfigError, match=r"unknown camera 'left' \(expected 'a' or 'b' or 'c'\)"):
        rig.camera("left")
    for doc, message in (
        ({"left": cam}, "right missing"),
        ({"left": cam, "right": cam, "rig": {"a": cam, "b": cam}}, "not both"),
        ({"rig": {"a": cam}}, "two cameras or more"),
        ({"rig": {"a/b": cam, "c": cam}}, "camera name 'a/b'"),
    ):
        with pytest.raises(ValueError, match=message):
            CaptureConfig.model_validate(doc)


def test_a_ring_recorded_to_mcap_reads_back_as_a_bag_of_four_topics(tmp_path: Path) -> None:
    from rig.capture.recorded import open_recording
    from rig.ros.mcap_export import McapRecordingWriter
    from rig.ros.names import RosNames

    cams = ("cam1", "cam2", "cam3", "cam4")
    source = write_set_recording(tmp_path / "ring", cams, 6, skews_ns=(0, 2_000_000, 1_000_000, 3_000_000))
    config, _ = replay_capture_config(source)
    with RigCapture(config) as capture:
        recorder = Recorder(capture, lambda: McapRecordingWriter(tmp_path / "ring.mcap", cameras=cams))
        assert recorder.run(max_seconds=60).pairs_written == 6
    recorder.complete()
    topics = {c: RosNames().raw_image(c, compressed=True) for c in cams}
    bag = open_recording(tmp_path / "ring.mcap", topics=topics)
    src = Recording(source)
    assert bag.cameras == list(cams)
    assert [row.stamps for row in bag.pairs] == [row.stamps for row in src.pairs]
    for row, orig in zip(bag.pairs, src.pairs, strict=True):
        for c in cams:
            assert bag.read_frame(row, c).raw == src.read_bytes(orig, c)
    # A topic that lags by more than the gate pairs with nothing: the bag is refused, named.
    with pytest.raises(RecordingError, match="are not synchronised"):
        open_recording(tmp_path / "ring.mcap", topics=topics, max_skew_ms=0.5)
