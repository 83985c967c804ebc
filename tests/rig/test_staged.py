"""The staged executor (rig.staged) against the pipeline's own one-call ``process``: the same
frames bit for bit, in order, with failing pairs reported by key and the stages going on."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from rig.errors import PipelineError, RecordingError
from rig.pipeline import DepthFrame
from rig.recording import Recording
from rig.staged import END, EndOfPairs, PairJob, StagedExecutor
from rig.stereo import StereoParams
from tests.helpers.offline import STEREO, TEMPORAL, make_pipeline, noisy_recording

N_PAIRS = 5


@pytest.fixture(scope="module")
def images(tmp_path_factory: pytest.TempPathFactory) -> list[tuple[NDArray[Any], NDArray[Any]]]:
    rec = Recording(noisy_recording(tmp_path_factory.mktemp("staged") / "rec", N_PAIRS))
    return [(rec.read_image(p, "left"), rec.read_image(p, "right")) for p in rec.pairs]


def _raise(err: Exception) -> NDArray[Any]:
    raise err


def _run(
    stages_of: StereoParams, jobs: list[PairJob[int]], cache: Path, *, deliver_thread: bool
) -> tuple[list[DepthFrame], dict[int, BaseException]]:
    pipeline = make_pipeline(stages_of, cache)
    todo: list[PairJob[int] | EndOfPairs] = [*jobs, END]
    delivered: list[DepthFrame] = []
    errors: dict[int, BaseException] = {}
    lock = threading.Lock()

    def take(timeout_s: float) -> PairJob[int] | EndOfPairs | None:
        with lock:
            return todo.pop(0) if todo else None

    def deliver(key: int, frame: DepthFrame, timings: dict[str, float]) -> None:
        assert key == frame.seq and timings["total"] >= timings["match"] > 0.0
        delivered.append(frame)

    def on_error(key: int | None, err: BaseException) -> None:
        assert key is not None, err
        errors[key] = err

    stages = StagedExecutor(pipeline, take, deliver, on_error=on_error, deliver_thread=deliver_thread)
    stages.start()
    try:
        assert stages.wait(120.0), "the source's END never passed the stages"
    finally:
        stages.stop()
    return delivered, errors


@pytest.mark.parametrize("stereo", [STEREO, TEMPORAL], ids=["defaults", "temporal"])
def test_staged_frames_equal_process_bit_for_bit(
    images: list[tuple[NDArray[Any], NDArray[Any]]], stereo: StereoParams, tmp_path: Path
) -> None:
    jobs = [
        PairJob(seq, seq, seq * 10, lambda left=left: left, lambda right=right: right)
        for seq, (left, right) in enumerate(images)
    ]
    staged, errors = _run(stereo, jobs, tmp_path, deliver_thread=True)
    assert not errors
    reference = make_pipeline(stereo, tmp_path)
    expected = [reference.process(left, right, seq, seq * 10) for seq, (left, right) in enumerate(images)]
    assert [f.seq for f in staged] == list(range(N_PAIRS))
    for got, want in zip(staged, expected, strict=True):
        assert got.ts_ns == want.ts_ns
        for name in ("depth", "disparity", "confidence", "valid", "left_rect", "right_rect"):
            assert np.array_equal(getattr(got, name), getattr(want, name), equal_nan=True), (got.seq, name)
    if stereo.temporal_alpha:
        # The history matters on these frames: the last pair alone (no history) differs.
        alone = make_pipeline(stereo, tmp_path).process(*images[-1])
        assert not np.array_equal(alone.disparity, staged[-1].disparity, equal_nan=True)


def test_failing_pairs_are_reported_by_key_and_the_rest_keep_their_order(
    images: list[tuple[NDArray[Any], NDArray[Any]]], tmp_path: Path
) -> None:
    left, right = images[0]
    small = left[: left.shape[0] // 2]
    jobs = [
        PairJob(0, 0, 0, lambda: left, lambda: right),
        PairJob(1, 1, 0, lambda: _raise(RecordingError("frame 1 unreadable")), lambda: right),
        PairJob(2, 2, 0, lambda: left, lambda: right),
        PairJob(3, 3, 0, lambda: small, lambda: right),  # wrong size: the pipeline refuses it
        PairJob(4, 4, 0, lambda: left, lambda: right),
    ]
    delivered, errors = _run(STEREO, jobs, tmp_path, deliver_thread=False)
    assert [f.seq for f in delivered] == [0, 2, 4]
    assert sorted(errors) == [1, 3]
    assert isinstance(errors[1], RecordingError) and "frame 1 unreadable" in str(errors[1])
    assert isinstance(errors[3], PipelineError) and "calibration" in str(errors[3])
