"""rig.process in this process: the files of a staged run against the pipeline's one-call
``process`` and OpenCV's PNG encoder, chunks with the temporal filter's history carried, resume,
and what a run does with an earlier run's files."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.atomic import TEMP_MARK
from rig.depth import depth_to_png_mm
from rig.errors import ConfigError
from rig.outputs import OutputLayout
from rig.process import process_recordings
from rig.recording import Recording
from rig.recording_depth import process_pairs
from rig.recording_jobs import ProcessOptions, RecordingJob, RecordingSource, plan_recording
from rig.stereo import StereoParams
from tests.helpers.offline import STEREO, TEMPORAL, files_of, make_pipeline, noisy_recording

N_PAIRS = 6


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return noisy_recording(tmp_path_factory.mktemp("offline") / "rec", N_PAIRS, first_seq=10)


def _run(rec: Path, out: Path, stereo: StereoParams, cache: Path, **options: object) -> list[object]:
    job = RecordingJob(RecordingSource(rec), Recording(rec), make_pipeline(stereo, cache), out)
    # The pinhole pair's products (BASE_PRODUCTS and its depth/).
    options.setdefault("products", ("range", "depth", "left", "right"))
    return list(process_recordings([job], ProcessOptions(**options)))  # type: ignore[arg-type]


def _png(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", image)
    assert ok
    return bytes(buf.tobytes())


@pytest.mark.parametrize("stereo", [STEREO, TEMPORAL], ids=["defaults", "temporal"])
def test_files_equal_a_sequential_loop_bit_for_bit(rec: Path, stereo: StereoParams, tmp_path: Path) -> None:
    (summary,) = _run(rec, tmp_path / "out", stereo, tmp_path / "c")
    assert (summary.written, summary.resumed, summary.failures) == (N_PAIRS, 0, [])  # type: ignore[attr-defined]
    recording = Recording(rec)
    pipeline = make_pipeline(stereo, tmp_path / "c")
    for pair in recording.pairs:
        left, right = (recording.read_frame(pair, cam).pipeline_image() for cam in ("left", "right"))
        frame = pipeline.process(left, right, pair.seq)
        stem = f"{pair.seq:06d}.png"
        assert (tmp_path / "out" / "range" / stem).read_bytes() == _png(depth_to_png_mm(frame.range))
        assert (tmp_path / "out" / "depth" / stem).read_bytes() == _png(depth_to_png_mm(frame.depth))
        assert (tmp_path / "out" / "left" / stem).read_bytes() == _png(frame.left_rect)
        assert (tmp_path / "out" / "right" / stem).read_bytes() == _png(frame.right_rect)


def test_chunks_carrying_the_temporal_history_equal_one_run(rec: Path, tmp_path: Path) -> None:
    recording = Recording(rec)
    pairs = recording.pairs
    whole, carried, dropped = (OutputLayout(tmp_path / n) for n in ("whole", "carried", "dropped"))
    for layout in (whole, carried, dropped):
        for sub in ("range", "left", "right"):
            (layout.root / sub).mkdir(parents=True)
    pipeline = make_pipeline(TEMPORAL, tmp_path / "c")
    process_pairs(pipeline, recording, pairs, whole.sink(pipeline))
    state = None
    for part in (pairs[:2], pairs[2:5], pairs[5:]):
        # A fresh pipeline per chunk, as on another worker: only the history carries over.
        chunk = make_pipeline(TEMPORAL, tmp_path / "c")
        result = process_pairs(chunk, recording, part, carried.sink(chunk), temporal_state=state)
        assert result.temporal_state is not None
        state = result.temporal_state
        alone = make_pipeline(TEMPORAL, tmp_path / "c")
        process_pairs(alone, recording, part, dropped.sink(alone))
    assert files_of(carried.root) == files_of(whole.root)
    # Without the history the chunks' first pairs come out otherwise: the carry is what matters.
    differ = [k for k, v in files_of(dropped.root).items() if files_of(whole.root)[k] != v]
    assert all(k.startswith("range/") for k in differ)
    assert {"range/000012.png", "range/000015.png"} <= set(differ)  # each chunk's first pair
    assert not {"range/000010.png", "range/000011.png"} & set(differ)  # the first chunk is the run


def test_resume_writes_only_what_is_missing(rec: Path, tmp_path: Path) -> None:
    out, reference = tmp_path / "out", tmp_path / "reference"
    _run(rec, reference, STEREO, tmp_path / "c")
    _run(rec, out, STEREO, tmp_path / "c")
    (out / "depth" / "000012.png").unlink()
    (out / "left" / "000014.png").unlink()
    stale = out / "right" / f".000015.png{TEMP_MARK}999-1-0"  # a writer killed mid-file
    stale.write_bytes(b"half a png")
    before = {p: p.stat().st_mtime_ns for p in (out / "depth").iterdir()}
    (summary,) = _run(rec, out, STEREO, tmp_path / "c", resume=True)
    assert (summary.written, summary.resumed) == (2, N_PAIRS - 2)  # type: ignore[attr-defined]
    assert not stale.exists()
    assert files_of(out) == files_of(reference)
    untouched = out / "depth" / "000010.png"
    assert untouched.stat().st_mtime_ns == before[untouched]


def test_resume_with_the_temporal_filter_rebuilds_its_history(rec: Path, tmp_path: Path) -> None:
    out, reference = tmp_path / "out", tmp_path / "reference"
    _run(rec, reference, TEMPORAL, tmp_path / "c")
    _run(rec, out, TEMPORAL, tmp_path / "c")
    (out / "depth" / "000014.png").unlink()
    job = RecordingJob(RecordingSource(rec), Recording(rec), make_pipeline(TEMPORAL, tmp_path / "c"), out)
    plan_recording(job, ProcessOptions(resume=True, products=("range", "depth", "left", "right")))
    assert job.write == {14}
    assert [p.seq for p in job.compute] == [10, 11, 12, 13, 14]  # the history up to the missing pair
    (summary,) = _run(rec, out, TEMPORAL, tmp_path / "c", resume=True)
    assert summary.written == 1  # type: ignore[attr-defined]
    assert files_of(out) == files_of(reference)


def test_resume_refuses_files_made_with_other_settings(rec: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    _run(rec, out, STEREO, tmp_path / "c")
    with pytest.raises(ConfigError, match=r"run\.json: .*stereo\.disparity_range differs"):
        _run(rec, out, StereoParams(disparity_range=48), tmp_path / "c", resume=True)
    with pytest.raises(ConfigError, match=r"products differs"):
        _run(
            rec,
            out,
            STEREO,
            tmp_path / "c",
            resume=True,
            products=("range", "depth", "left", "right", "preview"),
        )


def test_resume_refuses_the_files_of_another_recording(rec: Path, tmp_path: Path) -> None:
    # Another recording with the same index (seqs, capture times) and other frames.
    other = noisy_recording(tmp_path / "other", N_PAIRS, seed=7, first_seq=10)
    out = tmp_path / "out"
    _run(rec, out, STEREO, tmp_path / "c")
    before = files_of(out)
    with pytest.raises(
        ConfigError, match=r"run\.json: the files there were made from another recording \(.*rec\)"
    ):
        _run(other, out, STEREO, tmp_path / "c", resume=True)
    assert files_of(out) == before  # the files kept, run.json still naming the first recording
    # The same recording elsewhere is the same recording: nothing to redo.
    moved = tmp_path / "moved"
    shutil.copytree(rec, moved)
    (summary,) = _run(moved, out, STEREO, tmp_path / "c", resume=True)
    assert (summary.written, summary.resumed) == (0, N_PAIRS)  # type: ignore[attr-defined]


def test_a_new_run_first_removes_an_earlier_runs_files_of_its_pairs(rec: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    _run(rec, out, STEREO, tmp_path / "c", products=("range", "depth", "left", "right", "cloud"))
    assert len(list((out / "cloud").iterdir())) == N_PAIRS
    other = tmp_path / "other"
    _run(rec, other, StereoParams(disparity_range=48), tmp_path / "c")
    # A run with other settings and no clouds: nothing of the earlier run is left to mix in.
    job = RecordingJob(
        RecordingSource(rec),
        Recording(rec),
        make_pipeline(StereoParams(disparity_range=48), tmp_path / "c"),
        out,
    )
    plan_recording(job, ProcessOptions())
    assert list((out / "cloud").iterdir()) == [] and list((out / "depth").iterdir()) == []
    _run(rec, out, StereoParams(disparity_range=48), tmp_path / "c")
    assert {k: v for k, v in files_of(out).items() if k != "run.json"} == {
        k: v for k, v in files_of(other).items() if k != "run.json"
    }


def test_unreadable_pairs_are_failures_with_their_reason(rec: Path, tmp_path: Path) -> None:
    broken = noisy_recording(tmp_path / "broken", 4)
    (broken / "left" / "000001.png").write_bytes(b"\x89PNG\r\n\x1a\n not an image")
    (broken / "right" / "000002.png").unlink()
    (summary,) = _run(broken, tmp_path / "out", STEREO, tmp_path / "c")
    failures = {f.seq: f.reason for f in summary.failures}  # type: ignore[attr-defined]
    assert sorted(failures) == [1, 2] and summary.written == 2  # type: ignore[attr-defined]
    assert "000001.png: not a readable image" in failures[1]
    assert "000002.png" in failures[2] and "unreadable" in failures[2]
    assert sorted(p.name for p in (tmp_path / "out" / "depth").iterdir()) == ["000000.png", "000003.png"]
