"""The demo recording: rendered by rig.sim, cached by key, never used half-rendered."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calibration import load_rig
from rig.recording import Recording
from rig.rectified import RectifiedPairConfig
from service.demo import DemoSpec, demo_key, demo_overrides, ensure_demo_recording
from service.settings import load_settings

TINY = DemoSpec(scale=0.125, frames=2, supersample=1, vpc=RectifiedPairConfig(width=48, height=32))


def test_key_changes_with_every_field() -> None:
    keys = {
        demo_key(TINY),
        demo_key(DemoSpec(scale=0.125, frames=3, supersample=1, vpc=TINY.vpc)),
        demo_key(DemoSpec(scale=0.125, frames=2, supersample=1, seed=1, vpc=TINY.vpc)),
        demo_key(
            DemoSpec(scale=0.125, frames=2, supersample=1, vpc=RectifiedPairConfig(width=48, height=30))
        ),
        demo_key(DemoSpec()),
    }
    assert len(keys) == 5
    assert demo_key(TINY) == demo_key(
        DemoSpec(scale=0.125, frames=2, supersample=1, vpc=RectifiedPairConfig(width=48, height=32))
    )


def test_interrupted_render_is_never_used_then_cached(tmp_path: Path) -> None:
    calls: list[tuple[str, int, int]] = []

    def interrupt(step: str, done: int, total: int) -> None:
        calls.append((step, done, total))
        if step == "noise" and done == 1:
            raise KeyboardInterrupt  # Ctrl+C in the middle of the render

    with pytest.raises(KeyboardInterrupt):
        ensure_demo_recording(TINY, tmp_path, progress=interrupt)
    assert list(tmp_path.iterdir()) == []  # nothing half-made left to be trusted

    calls.clear()
    loop = ensure_demo_recording(TINY, tmp_path, progress=lambda *a: calls.append(a))
    assert calls[-1] == ("noise", 2, 2)
    assert loop == tmp_path / demo_key(TINY) / "loop"
    rec = Recording(loop)
    assert len(rec.pairs) == 2 and rec.meta["demo"]["frames"] == 2
    assert rec.pairs[1].left_ts_ns - rec.pairs[0].left_ts_ns == round(1e9 / 30)
    rig = load_rig(loop / "calibration.yaml")
    img = rec.read_image(rec.pairs[0], "left")
    assert img.shape == (rig.cameras["left"].height, rig.cameras["left"].width)
    # The two frames are the same view with different noise.
    other = rec.read_image(rec.pairs[1], "left").astype(int)
    diff = other - img.astype(int)
    assert 0 < np.abs(diff).mean() < 5

    calls.clear()
    assert ensure_demo_recording(TINY, tmp_path, progress=lambda *a: calls.append(a)) == loop
    assert calls == []  # cached: no render


def test_leftovers_of_a_dead_render_are_removed(tmp_path: Path) -> None:
    stale = tmp_path / f".{demo_key(TINY)}.tmp-999999999"
    (stale / "render").mkdir(parents=True)
    ensure_demo_recording(TINY, tmp_path, progress=lambda *a: None)
    assert not stale.exists()


def test_demo_overrides_load_as_settings(tmp_path: Path) -> None:
    loop = tmp_path / "loop"
    s = load_settings(None, demo_overrides(loop))
    assert s.cameras is not None
    for name in ("left", "right"):
        cam = s.cameras.camera(name)
        assert cam.kind == "file" and cam.recording == loop and cam.loop and cam.pace == 30.0
        assert cam.timestamps == "live" and cam.camera == name
    assert s.calibration.path == loop / "calibration.yaml"
    assert s.cameras.supervisor.decode == "auto"  # the service default: nothing decoded in vain
