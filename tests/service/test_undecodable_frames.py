"""A frame that passes the capture's structural check but does not decode, or whose header
declares a size other than the camera's (an image bomb, refused before it is decoded): file cameras →
StereoCapture → DepthWorker, as in the service. Whichever thread decodes it (the capture's with
``decode: true``, the worker's with ``decode: false``), it is counted against its camera, named in
its ``last_error``, and no depth is made from it; the worker reports no error of its own."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from rig.capture.capture import StereoCapture
from rig.capture.config import PairingConfig
from rig.capture.frame import encoded_problem
from rig.pipeline import DepthPipeline
from rig.recording import RecordingWriter
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams
from service.store import ResultStore
from service.worker import DepthWorker
from tests.helpers.recordings import FAST_SUPERVISOR, PERIOD_NS, T0_NS, encode, replay_config
from tests.helpers.shots import StereoShot, plane_shot
from tests.helpers.waiting import wait_for

PAIRS = 6
BAD_SEQ = 3
VPC = RectifiedPairConfig(width=320, height=240)


def _declaring(data: bytes, width: int, height: int) -> bytes:
    """The JPEG with its frame header (SOF0) declaring ``width``×``height``: every marker is in
    place, so it passes the structural check."""
    out = bytearray(data)
    sof = out.find(b"\xff\xc0")
    assert sof > 0
    out[sof + 5 : sof + 9] = height.to_bytes(2, "big") + width.to_bytes(2, "big")
    bad = bytes(out)
    assert encoded_problem(bad, "jpeg") is None
    return bad


def _undecodable(data: bytes) -> bytes:
    """0×0 pixels: libjpeg refuses it."""
    bad = _declaring(data, 0, 0)
    assert cv2.imdecode(np.frombuffer(bad, np.uint8), cv2.IMREAD_GRAYSCALE) is None
    return bad


def _bomb(data: bytes) -> bytes:
    """30000×30000 pixels: libjpeg would decode 900 MB (the missing data as grey)."""
    return _declaring(data, 30000, 30000)


BAD = {"undecodable": (_undecodable, "jpeg header unreadable"), "bomb": (_bomb, "declares 30000x30000")}


@pytest.fixture(scope="module")
def shot() -> StereoShot:
    return plane_shot(5.0, scale=0.5, vpc=VPC)


@pytest.fixture(scope="module", params=list(BAD))
def recording(
    request: pytest.FixtureRequest, shot: StereoShot, tmp_path_factory: pytest.TempPathFactory
) -> Path:
    root = tmp_path_factory.mktemp("undecodable") / request.param
    left, right = encode(shot.left, ".jpg", 95), encode(shot.right, ".jpg", 95)
    spoil = BAD[request.param][0]
    with RecordingWriter(root, meta={"source": "test"}) as w:
        for seq in range(PAIRS):
            ts = T0_NS + seq * PERIOD_NS
            w.write_pair(seq, ts, ts, left, spoil(right) if seq == BAD_SEQ else right, ext=".jpg")
    return root


@pytest.fixture(scope="module")
def pipe(shot: StereoShot, lut_cache: Path) -> DepthPipeline:
    return DepthPipeline(shot.rig, VPC, StereoParams(disparity_range=64), cache_dir=lut_cache)


@pytest.mark.parametrize("decode", [False, True], ids=["worker-decodes", "capture-decodes"])
def test_an_undecodable_frame_is_counted_against_its_camera(
    recording: Path, pipe: DepthPipeline, decode: bool
) -> None:
    # Unpaced replay with back-pressure and one pair buffered: the worker takes every pair.
    config = replay_config(
        recording,
        pace="fast",
        timestamps="recorded",
        supervisor=FAST_SUPERVISOR.model_copy(update={"decode": decode}),
        pairing=PairingConfig(backpressure=True, pair_buffer=1),
    )
    seen: list[int] = []
    capture = StereoCapture(config).start()
    worker = DepthWorker(capture, pipe, ResultStore(), on_result=lambda r, t: seen.append(r.seq), poll_s=0.02)
    worker.start()
    try:
        wait_for(lambda: capture.exhausted and len(seen) >= PAIRS - 1, 60.0, "the replay to end")
        health, stats = capture.health(), worker.stats()
    finally:
        worker.stop()
        capture.stop()
    assert seen == [s for s in range(PAIRS) if s != BAD_SEQ], "no depth from the bad pair, none lost"
    right, left = health.cameras["right"], health.cameras["left"]
    counted = (right.counters["frames_corrupt"], right.counters["frames_undecodable"])
    assert counted == ((1, 0) if decode else (0, 1))
    assert (left.counters["frames_corrupt"], left.counters["frames_undecodable"]) == (0, 0)
    why = BAD[recording.name][1]
    assert f"frame {BAD_SEQ}" in (right.last_error or "") and why in (right.last_error or ""), (
        right.last_error
    )
    assert right.state != "unavailable" and left.last_error is None
    # Received: the worker only sees frames that reached pairing; the capture's decode stops it before.
    assert right.counters["frames_received"] == PAIRS - (1 if decode else 0)
    assert stats.counters["errors"] == 0 and stats.last_error is None
