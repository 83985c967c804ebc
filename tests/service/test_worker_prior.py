"""The live worker's temporal prior through the whole service (rig.temporal_prior; docs/stereo.md):
a camera pair that sees the same images frame after frame has its search kept, /health and
/metrics count the frames that kept it, and the depth served is the search's."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rig.recording import Recording, RecordingWriter
from service.settings import load_settings
from tests.helpers.service import SmallRecording, in_process, service_overrides
from tests.helpers.waiting import wait_for

pytestmark = pytest.mark.timeout(120)


def _still(small: SmallRecording, out: Path, frames: int = 3) -> Path:
    """The small recording's first pair, ``frames`` times: a rig standing still in a still room."""
    source = Recording(small.loop)
    first = next(iter(source))
    left, right = (source.read_bytes(first, cam) for cam in ("left", "right"))
    ext = Path(first.file("left")).suffix
    with RecordingWriter(out, meta={"source": "test: the first pair repeated"}) as w:
        for seq in range(frames):
            ts = 1_000_000_000 + seq * 100_000_000
            w.write_pair(seq, ts, ts, left, right, ext=ext)
    (out / "calibration.yaml").write_bytes((small.loop / "calibration.yaml").read_bytes())
    return out


def _worker(server: Any) -> dict[str, Any]:
    worker: dict[str, Any] = server.client.get("/health").json()["worker"]
    return worker


@pytest.mark.parametrize("temporal_prior", [True, False])
def test_a_still_pair_keeps_its_search_and_the_service_counts_it(
    small_recording: SmallRecording, tmp_path: Path, lut_cache: Path, temporal_prior: bool
) -> None:
    recording = _still(small_recording, tmp_path / "still")
    doc = service_overrides(recording, tmp_path, lut_cache)
    doc["stereo"] = {**doc["stereo"], "temporal_prior": temporal_prior}
    with in_process(load_settings(None, doc)) as server:
        server.wait_ready()
        worker = wait_for(
            lambda: (w := _worker(server))["frames_processed"] >= 6 and w,
            timeout_s=60.0,
            what="six depth frames",
        )
        depth = server.client.get("/depth", params={"format": "npy"})
        metrics = server.client.get("/metrics").text
    kept, done = worker["searches_kept"], worker["frames_processed"]
    print(f"\ntemporal_prior {temporal_prior}: {kept} of {done} frames kept the last search")
    sample = [line for line in metrics.splitlines() if line.startswith("rig_worker_searches_kept_total ")]
    assert len(sample) == 1 and float(sample[0].split()[1]) >= kept
    if temporal_prior:
        # The first frame is searched, then nothing changes (at most one periodic search in 30).
        assert done - 2 <= kept < done
    else:
        assert kept == 0
    assert depth.status_code == 200
    served = np.load(io.BytesIO(depth.content))
    assert np.isfinite(served).mean() > 0.3
