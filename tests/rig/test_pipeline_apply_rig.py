"""``DepthPipeline.apply(rig=...)``: a corrected calibration swapped into a running pipeline gives
what a pipeline built on it gives, a pair rectified before the swap finishes with the geometry it
began with, and only a rotation-and-direction change of the same lenses and baseline is taken;
the ROS message builder follows the swap."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from calibration.rig import Rig
from rig.errors import ConfigError
from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from rig.ros.messages import MessageBuilder
from tests.rig.rectification_renders import perturbed
from tests.rig.ros_fixtures import STEREO, VPC, shot


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.array_equal(a, b, equal_nan=True))


def _equal(a: object, b: object) -> bool:
    """Deep equality of dataclasses, mappings and sequences holding numpy arrays."""
    if dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b):
        return type(a) is type(b) and _equal(dataclasses.asdict(a), dataclasses.asdict(b))  # type: ignore[arg-type]
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return bool(np.array_equal(np.asarray(a), np.asarray(b)))
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def test_a_swapped_pipeline_equals_one_built_on_the_corrected_rig(tmp_path: Path) -> None:
    s = shot()
    pipe = DepthPipeline(s.rig, VPC, STEREO, cache_dir=tmp_path)
    corrected = perturbed(s.rig, (0.2, -0.3, 0.1))
    before = pipe.rectify(s.left, s.right)  # in flight across the swap
    old = pipe.geometry
    before_revision = pipe.in_effect.revision
    new = pipe.apply(rig=corrected)
    assert pipe.in_effect is new and pipe.geometry is new.geometry and pipe.rig is corrected
    assert new.geometry is not old and new.revision == before_revision + 1
    assert new.stereo is STEREO or new.stereo == STEREO  # the stereo parameters stay in effect
    assert not np.allclose(new.pair.R_cam_rect["right"], old.pair.R_cam_rect["right"])
    # The pair rectified before the swap keeps its geometry to the end.
    assert before.geometry is old
    finished = pipe.postprocess(pipe.match(before))
    reference_old = DepthPipeline(s.rig, VPC, STEREO, cache_dir=tmp_path).process(s.left, s.right)
    assert _same(finished.disparity, reference_old.disparity)
    # Pairs after the swap: exactly what a pipeline built on the corrected rig makes.
    after = pipe.process(s.left, s.right)
    reference_new = DepthPipeline(corrected, VPC, STEREO, cache_dir=tmp_path).process(s.left, s.right)
    assert _same(after.left_rect, reference_new.left_rect) and _same(
        after.right_rect, reference_new.right_rect
    )
    assert _same(after.depth, reference_new.depth)
    assert not _same(after.right_rect, reference_old.right_rect)


def test_only_the_same_lenses_and_baseline_are_taken(tmp_path: Path) -> None:
    s = shot()
    pipe = DepthPipeline(s.rig, VPC, STEREO, cache_dir=tmp_path)
    other_lens = s.rig.cameras["right"].replace(fx=s.rig.cameras["right"].param_dict["fx"] * 1.01)
    with pytest.raises(ConfigError, match="not the same lens"):
        pipe.apply(rig=Rig({"left": s.rig.cameras["left"], "right": other_lens}, dict(s.rig.T_rig_cam)))
    with pytest.raises(ConfigError, match="baseline changes"):
        pipe.apply(rig=perturbed(s.rig, (0.0, 0.0, 0.0), along_baseline_m=0.001))
    assert pipe.rig is s.rig


def test_ros_messages_follow_the_swap(tmp_path: Path) -> None:
    s = shot()
    pipe = DepthPipeline(s.rig, VPC, STEREO, cache_dir=tmp_path)
    builder = MessageBuilder(pipe)
    old_info, old_tf = builder.raw_infos["right"], builder.transforms
    corrected = perturbed(s.rig, (0.2, -0.3, 0.1))
    pipe.apply(rig=corrected)
    fresh = MessageBuilder(DepthPipeline(corrected, VPC, STEREO, cache_dir=tmp_path))
    assert _equal(builder.raw_infos, fresh.raw_infos) and _equal(builder.rect_infos, fresh.rect_infos)
    assert _equal(builder.transforms, fresh.transforms)
    assert not _equal(builder.raw_infos["right"], old_info) and not _equal(builder.transforms, old_tf)


def test_a_lat_lon_pair_keeps_its_image_grid_across_a_swap(tmp_path: Path) -> None:
    """A corrected calibration moves the lenses' overlap, and with it a default lat-lon field;
    the swap keeps the running pair's image grid (frames in flight, the finish stage and the
    temporal filter share it) and takes the corrected rotation."""
    s = shot()
    vpc = RectifiedPairConfig(projection="latlon", px_per_deg=1.5)
    pipe = DepthPipeline(s.rig, vpc, STEREO, cache_dir=tmp_path)
    old = pipe.geometry
    before = pipe.process(s.left, s.right)
    corrected = perturbed(s.rig, (0.5, -0.5, 0.3))
    new = pipe.apply(rig=corrected)
    assert new.pair.camera == old.pair.camera
    redesigned = design_rectified_pair(corrected, vpc, blind_band_px=STEREO.blind_band_px)
    for name in ("left", "right"):
        assert np.allclose(new.pair.R_cam_rect[name], redesigned.R_cam_rect[name], atol=1e-12)
    assert not np.allclose(new.pair.R_cam_rect["right"], old.pair.R_cam_rect["right"])
    after = pipe.process(s.left, s.right)
    assert after.range.shape == before.range.shape == (old.pair.camera.height, old.pair.camera.width)
    valid_before, valid_after = np.isfinite(before.range).mean(), np.isfinite(after.range).mean()
    print(f"lat-lon valid range before/after the swap: {valid_before:.3f} / {valid_after:.3f}")
    assert valid_before > 0.3 and valid_after > 0.9 * valid_before  # measured 0.349 / 0.343
