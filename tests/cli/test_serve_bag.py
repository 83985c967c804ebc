"""``rig serve --recording BAG --left-topic T --right-topic T``: the settings it builds replay the
bag through the file cameras, and the service makes depth from it."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin

from calibration import save_rig
from cli.errors import CommandError
from cli.serve import serve_settings
from rig.capture.config import FileCameraConfig
from service.runtime import Runtime
from tests.rig.ros_fixtures import shot
from tests.rig.test_capture_bag import LEFT, RIGHT, STAMPS, write_bag


def test_serve_replays_a_bag(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RIG_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("RIG_VPC__WIDTH", "160")
    monkeypatch.setenv("RIG_VPC__HEIGHT", "120")
    monkeypatch.setenv("RIG_STEREO__DISPARITY_RANGE", "32")
    write_bag(tmp_path / "bag", StoragePlugin.MCAP, left_stamps=STAMPS, right_stamps=STAMPS)
    save_rig(shot().rig, tmp_path / "rig.yaml")
    bag = {"left_topic": LEFT, "right_topic": RIGHT, "max_skew_ms": None}
    with pytest.raises(CommandError, match="name its two image topics"):
        serve_settings(None, recording=tmp_path / "bag", calibration=tmp_path / "rig.yaml")
    settings = serve_settings(None, recording=tmp_path / "bag", calibration=tmp_path / "rig.yaml", bag=bag)
    assert settings.cameras is not None
    left = settings.cameras.left
    assert isinstance(left, FileCameraConfig) and (left.left_topic, left.right_topic) == (LEFT, RIGHT)
    runtime = Runtime.build(settings)
    runtime.start()
    try:
        deadline = time.monotonic() + 30
        while runtime.store.latest is None or runtime.store.latest.index < 3:
            assert time.monotonic() < deadline, runtime.health().reasons
            time.sleep(0.05)
        depth = runtime.store.latest.frame.depth
        assert depth.shape == (120, 160) and np.isfinite(depth).mean() > 0.5
        assert runtime.health().capture.cameras["left"].kind == "file"
    finally:
        runtime.stop()
