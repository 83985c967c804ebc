"""The depth pipeline of a rig of N cameras (rig.rig_pipeline) and over a recording of N cameras
(rig.rig_depth): a pipeline per pair, the panorama fused; on the staged executor the same depth,
bit for bit, as one pair after another; a set missing a frame skipped whole; the two-camera rig is
today's pipeline."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from rig.errors import RecordingError
from rig.pipeline import DepthPipeline
from rig.recording import Recording
from rig.rectified import RectifiedPairConfig
from rig.rig_depth import check_recording_cameras, process_sets, read_set_images
from rig.rig_pipeline import RigFrame, RigPipeline
from rig.sim import get_preset
from tests.helpers.recordings import write_recording
from tests.helpers.rings import (
    SMALL_RING_CONFIG,
    SMALL_RING_PANORAMA_PX_PER_DEG,
    small_ring_preset,
    write_small_ring,
)

RING_PAIRS = ["cam1-cam2", "cam2-cam3", "cam3-cam4", "cam4-cam1"]


@pytest.fixture(scope="module")
def ring(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_small_ring(tmp_path_factory.mktemp("ring") / "rec")


@pytest.fixture(scope="module")
def pipeline(lut_cache: Path) -> RigPipeline:
    return RigPipeline(
        small_ring_preset().rig,
        SMALL_RING_CONFIG,
        cache_dir=lut_cache,
        panorama_px_per_deg=SMALL_RING_PANORAMA_PX_PER_DEG,
    )


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.array_equal(a, b, equal_nan=True))


def test_a_two_camera_rig_is_todays_pipeline(lut_cache: Path) -> None:
    rig = get_preset("prototype").scaled(0.25).rig
    config = RectifiedPairConfig(px_per_deg=2.0)
    both = RigPipeline(rig, config, cache_dir=lut_cache)
    today = DepthPipeline(rig, config, cache_dir=lut_cache)
    assert both.labels == ["left-right"] and both.cameras == ["left", "right"]
    assert both.first.pair_config == today.pair_config
    rng = np.random.default_rng(1)
    images = {n: rng.integers(0, 256, (240, 320), dtype=np.uint8) for n in ("left", "right")}
    frame = both.process(images, seq=3)
    alone = today.process(images["left"], images["right"], seq=3)
    assert _same(frame.pairs["left-right"].range, alone.range)
    assert frame.seq == 3 and set(frame.timings_ms) == {"left-right", "panorama", "total"}


def test_sets_on_the_executor_are_the_pairs_one_after_the_other(ring: Path, pipeline: RigPipeline) -> None:
    assert pipeline.labels == RING_PAIRS
    rec = Recording(ring)
    got: dict[int, RigFrame] = {}
    result = process_sets(pipeline, rec, rec.pairs, lambda s, f: got.__setitem__(s.seq, f))
    assert (result.written, result.failures) == (2, [])
    for row in rec.pairs:
        images = read_set_images(rec, row, pipeline.rig, pipeline.cameras)
        alone = pipeline.process(images, row.seq, row.first_ts_ns)
        staged = got[row.seq]
        assert list(staged.pairs) == RING_PAIRS
        for label in RING_PAIRS:
            assert _same(staged.pairs[label].range, alone.pairs[label].range), label
            assert _same(staged.pairs[label].disparity, alone.pairs[label].disparity), label
        assert _same(staged.panorama.range, alone.panorama.range)
        assert np.array_equal(staged.panorama.flags, alone.panorama.flags)
        # The panorama ranges most of what two lenses see; each pair ranges its view.
        ranged = np.isfinite(staged.panorama.range).mean()
        print(f"small ring set {row.seq}: panorama ranges {100 * ranged:.1f} % of the sphere")
        assert ranged > 0.3
        points, colours = pipeline.point_cloud(staged, stride=2)
        assert points.shape == colours.shape and points.shape[0] > 1000
        # The fused cloud's points lie at the panorama's range from its origin.
        dist = np.linalg.norm(points - pipeline.panorama.origin, axis=1)
        pano = staged.panorama.range[::2, ::2]
        assert np.allclose(np.sort(dist), np.sort(pano[np.isfinite(pano)]), rtol=1e-5)


def test_a_set_missing_a_frame_is_skipped_whole(ring: Path, pipeline: RigPipeline, tmp_path: Path) -> None:
    broken = shutil.copytree(ring, tmp_path / "broken")
    (broken / "cam3" / "000001.png").unlink()
    rec = Recording(broken)
    seen: list[int] = []
    result = process_sets(pipeline, rec, rec.pairs, lambda s, f: seen.append(s.seq))
    assert seen == [0] and result.written == 1
    assert [f.seq for f in result.failures] == [1]
    assert "cam3/000001.png" in result.failures[0].reason


def test_a_recording_missing_a_camera_of_the_calibration_is_refused(tmp_path: Path) -> None:
    rec = Recording(write_recording(tmp_path / "pair", 2))
    with pytest.raises(RecordingError) as caught:
        check_recording_cameras(rec, ["cam1", "cam2"])
    assert str(caught.value) == (
        f"{tmp_path / 'pair' / 'recording.json'}: field 'cameras': no camera 'cam1', 'cam2' of the "
        "calibration (the recording has left, right)"
    )
