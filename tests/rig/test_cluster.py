"""rig.process on a real Dask LocalCluster of two worker processes: the outputs equal a run in
this process bit for bit (defaults and the temporal filter, whose history crosses chunks), and a
worker killed mid-run has its chunk retried elsewhere with the output still bit for bit."""

from __future__ import annotations

import logging
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import distributed
import pytest

from calibration.atomic import is_temporary
from rig.process import process_recordings
from rig.recording import Recording
from rig.recording_jobs import ProcessOptions, RecordingJob, RecordingSource, RecordingSummary
from rig.stereo import StereoParams
from tests.helpers.offline import STEREO, TEMPORAL, files_of, make_pipeline, noisy_recording


@pytest.fixture(scope="module")
def cluster() -> Iterator[Any]:
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=logging.ERROR
    ) as local:
        yield local


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    root = tmp_path_factory.mktemp("cluster")
    return [noisy_recording(root / "a", 6, seed=1), noisy_recording(root / "b", 5, seed=2, first_seq=3)]


def _jobs(recordings: list[Path], out: Path, stereo: StereoParams, cache: Path) -> list[RecordingJob]:
    pipeline = make_pipeline(stereo, cache)  # one calibration: one pipeline, its tables shipped once
    return [RecordingJob(RecordingSource(r), Recording(r), pipeline, out / r.name) for r in recordings]


def _run(jobs: list[RecordingJob], scheduler: str | None, chunk_pairs: int = 2) -> list[RecordingSummary]:
    return process_recordings(jobs, ProcessOptions(chunk_pairs=chunk_pairs), scheduler=scheduler)


@pytest.mark.parametrize("stereo", [STEREO, TEMPORAL], ids=["defaults", "temporal"])
def test_cluster_output_equals_this_process_bit_for_bit(
    cluster: Any, recordings: list[Path], stereo: StereoParams, tmp_path: Path
) -> None:
    here = _run(_jobs(recordings, tmp_path / "here", stereo, tmp_path / "c"), None)
    there = _run(_jobs(recordings, tmp_path / "there", stereo, tmp_path / "c"), cluster.scheduler_address)
    assert [(s.name, s.written, s.failures) for s in there] == [("a", 6, []), ("b", 5, [])]
    assert [(s.name, s.written) for s in here] == [("a", 6), ("b", 5)]
    for name in ("a", "b"):
        got, want = files_of(tmp_path / "there" / name), files_of(tmp_path / "here" / name)
        assert len(got) == 3 * (6 if name == "a" else 5) + 2  # range, left, right; vpc.json, run.json
        assert got == want, name


def _pids(client: Any) -> dict[str, int]:
    return dict(client.run(os.getpid))


def test_a_killed_workers_chunk_is_retried_and_the_output_stays_bit_for_bit(
    cluster: Any, recordings: list[Path], tmp_path: Path
) -> None:
    long = noisy_recording(tmp_path / "long", 12, seed=3)
    reference = _run(_jobs([long], tmp_path / "here", STEREO, tmp_path / "c"), None)
    assert reference[0].written == 12
    out = tmp_path / "there"
    summaries: list[RecordingSummary] = []
    run = threading.Thread(
        target=lambda: summaries.extend(
            _run(_jobs([long], out, STEREO, tmp_path / "c"), cluster.scheduler_address, 3)
        )
    )
    killed: dict[str, Any] = {}
    with distributed.Client(cluster.scheduler_address) as client:
        pids = _pids(client)
        run.start()
        deadline = time.monotonic() + 120.0
        while not killed and time.monotonic() < deadline and run.is_alive():
            for worker, keys in client.processing().items():
                done = len(list((out / "long" / "range").glob("*.png"))) if (out / "long").exists() else 0
                if done and any(str(k).startswith("rig-chunk-long-") for k in keys):
                    os.kill(pids[worker], signal.SIGKILL)
                    killed.update(worker=worker, keys=list(keys), pairs_done=done)
                    break
            time.sleep(0.005)
        run.join(300.0)
        assert not run.is_alive()
        client.wait_for_workers(2, timeout=60.0)  # the nanny restarted it, for the next tests
    assert killed, "no chunk was seen running"
    assert 0 < killed["pairs_done"] < 12  # killed mid-run
    with pytest.raises(ProcessLookupError):
        os.kill(pids[killed["worker"]], 0)
    (summary,) = summaries
    assert (summary.written, summary.failures) == (12, [])  # the dead worker's chunk ran elsewhere
    assert files_of(out / "long") == files_of(tmp_path / "here" / "long")
    assert not [p for p in (out / "long").rglob("*") if is_temporary(p.name)]
    worker, keys, done = killed["worker"], killed["keys"], killed["pairs_done"]
    print(f"\nkilled worker {worker} holding {keys} after {done} of 12 pairs")
