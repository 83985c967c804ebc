"""The staged executor (rig.staged) against the pipeline's own one-call ``process``: the same
frames bit for bit, in order, with failing pairs reported by key and the stages going on, and
the stage times in the one convention (the two cameras' decode and remap summed)."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from rig.errors import PipelineError, RecordingError
from rig.pipeline import DepthFrame, DepthPipeline
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
    stages_of: StereoParams | DepthPipeline, jobs: list[PairJob[int]], cache: Path, *, deliver_thread: bool
) -> tuple[list[DepthFrame], dict[int, BaseException]]:
    pipeline = stages_of if isinstance(stages_of, DepthPipeline) else make_pipeline(stages_of, cache)
    todo: list[PairJob[int] | EndOfPairs] = [*jobs, END]
    delivered: list[DepthFrame] = []
    errors: dict[int, BaseException] = {}
    lock = threading.Lock()

    def take(timeout_s: float) -> PairJob[int] | EndOfPairs | None:
        with lock:
            return todo.pop(0) if todo else None

    def deliver(key: int, frame: DepthFrame) -> None:
        timings = frame.timings_ms
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


def test_decode_and_remap_times_are_both_cameras_summed(
    images: list[tuple[NDArray[Any], NDArray[Any]]], tmp_path: Path
) -> None:
    """DepthFrame's convention: the executor decodes and remaps the two cameras on two threads
    at once and still reports the sum of their times, as DepthPipeline.process does for the two
    remaps it runs one after the other (a maximum would be about half)."""
    pipeline = make_pipeline(STEREO, tmp_path)
    own: dict[str, list[float]] = {"decode": [], "remap": []}  # each camera's, timed inside the call
    rectify = pipeline.rectify_camera

    def timed_rectify(name: str, image: Any, geometry: Any = None) -> Any:
        t0 = time.perf_counter()
        try:
            return rectify(name, image, geometry)
        finally:
            own["remap"].append((time.perf_counter() - t0) * 1e3)

    def timed_load(image: NDArray[Any]) -> NDArray[Any]:
        t0 = time.perf_counter()
        ok, png = cv2.imencode(".png", image)
        assert ok
        try:
            return np.asarray(cv2.imdecode(png, cv2.IMREAD_UNCHANGED))
        finally:
            own["decode"].append((time.perf_counter() - t0) * 1e3)

    pipeline.rectify_camera = timed_rectify  # type: ignore[method-assign]
    left, right = images[0]
    job = PairJob(0, 0, 0, lambda: timed_load(left), lambda: timed_load(right))
    (frame,), errors = _run(pipeline, [job], tmp_path, deliver_thread=False)
    assert not errors and len(own["remap"]) == 2 and len(own["decode"]) == 2
    timings = frame.timings_ms
    cameras = " + ".join(f"{ms:.2f}" for ms in own["remap"])
    print(f"\nstaged: remap {timings['remap']:.2f} ms, the cameras' own {cameras} ms")
    assert timings["remap"] >= sum(own["remap"]) and timings["decode"] >= sum(own["decode"])
    assert set(timings) == {"decode", "remap", "match", "refine", "filters", "depth", "total"}
    assert timings["total"] == pytest.approx(sum(v for k, v in timings.items() if k != "total"))
    # The one-call pipeline: the same keys but decode (it is handed decoded images), the same sum.
    own["remap"].clear()
    alone = pipeline.process(left, right).timings_ms
    assert alone["remap"] >= sum(own["remap"]) and len(own["remap"]) == 2
    assert set(alone) == set(timings) - {"decode"}
