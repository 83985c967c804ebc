"""Where frames are decoded (``cameras.supervisor.decode``), through file cameras → supervisors →
StereoCapture: ``true`` every frame in the camera threads, ``false`` none, ``auto`` those that
arrive while a consumer waits in ``next_pair`` (it takes them), not those a busy consumer skips."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Literal

import pytest

from rig.capture.capture import StereoCapture
from rig.capture.config import CaptureConfig
from rig.capture.frame import FramePair
from tests.helpers.recordings import FAST_SUPERVISOR, replay_config, write_recording


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_recording(tmp_path_factory.mktemp("decode") / "rec", 30)


def _config(rec: Path, decode: bool | Literal["auto"]) -> CaptureConfig:
    supervisor = FAST_SUPERVISOR.model_copy(update={"decode": decode})
    return replay_config(rec, pace=30.0, loop=True, supervisor=supervisor)


def _decoded(pair: FramePair) -> tuple[bool, bool]:
    return pair.left.decoded, pair.right.decoded


def _busy_then_take(cap: StereoCapture) -> FramePair:
    """The newest pair after 0.3 s of not asking (a consumer busy with an earlier frame)."""
    time.sleep(0.3)
    pair = cap.next_pair(0.0)
    assert pair is not None
    return pair


def _waiting_takes(cap: StereoCapture, n: int) -> list[FramePair]:
    """``n`` pairs taken by a consumer that is always waiting for the next one."""
    cap.next_pair(0.0)  # start from an empty buffer: the next pair forms while we wait
    pairs = []
    for _ in range(n):
        pair = cap.next_pair(2.0)
        assert pair is not None
        pairs.append(pair)
    return pairs


def test_auto_decodes_what_a_waiting_consumer_takes_and_skips_the_rest(rec: Path) -> None:
    with StereoCapture(_config(rec, "auto")) as cap:
        assert cap.next_pair(5.0) is not None  # running
        skipped = _busy_then_take(cap)
        waited = _waiting_takes(cap, 6)
    assert _decoded(skipped) == (False, False), "nobody was waiting: left for the consumer"
    # Both frames of a pair arrive within a millisecond while the consumer waits; allow for a
    # test thread descheduled between two calls on a loaded machine.
    both = sum(_decoded(p) == (True, True) for p in waited)
    assert both >= 4, [_decoded(p) for p in waited]


@pytest.mark.parametrize("decode", [True, False])
def test_true_and_false_decode_every_frame_or_none(rec: Path, decode: bool) -> None:
    with StereoCapture(_config(rec, decode)) as cap:
        assert cap.next_pair(5.0) is not None
        pairs = [_busy_then_take(cap), *_waiting_takes(cap, 3)]
    assert all(_decoded(p) == (decode, decode) for p in pairs)
