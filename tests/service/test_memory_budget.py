"""The memory budget: estimated from the settings before anything is built, a size that cannot fit
refused at start-up with its reason, a tight one warned about, the budget exported."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

import service.memory
from rig.memory_budget import FRAMES_ALIVE, MIB, available_memory
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from service.errors import SettingsError
from service.memory import service_estimate
from service.runtime import Runtime
from tests.helpers.service import InProcessServer, SmallRecording, service_settings


def test_a_vpc_that_cannot_fit_is_refused_before_any_table_is_built(
    small_recording: SmallRecording, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cache = tmp_path / "lut-cache"
    settings = service_settings(small_recording.loop, tmp_path, cache)
    huge = settings.model_copy(
        update={"rectified": settings.rectified.model_copy(update={"width": 4096, "height": 3072})}
    )
    monkeypatch.setattr(service.memory, "available_memory", lambda: 1024 * MIB)  # a 1 GiB board
    with pytest.raises(SettingsError) as refused:
        Runtime.build(huge)
    message = str(refused.value)
    assert "field 'rectified': a 4096x3072 pinhole pair with 64 disparities needs about" in message
    assert "more than the 1024 MiB this machine has left" in message and "rectified frames" in message
    assert not cache.exists() or not any(cache.iterdir())  # no table was built


def test_a_tight_budget_is_warned_about(
    small_recording: SmallRecording, tmp_path: Path, lut_cache: Path, caplog: pytest.LogCaptureFixture
) -> None:
    settings = service_settings(small_recording.loop, tmp_path, lut_cache)
    runtime = Runtime.build(settings)
    estimate = runtime.memory_budget
    now = runtime.pipeline.in_effect
    with caplog.at_level(logging.WARNING, logger="service.memory"):
        service.memory.check_memory(estimate, now.pair, now.stereo, available=int(estimate.total / 0.9))
    assert "needs about" in caplog.text and "320x240 pinhole pair" in caplog.text
    caplog.clear()
    service.memory.check_memory(estimate, now.pair, now.stereo, available=4 * estimate.total)
    assert caplog.text == ""


def test_the_lat_lon_budget_is_sized_by_the_pair_in_effect_and_its_advice_fits_it(
    small_recording: SmallRecording, tmp_path: Path, lut_cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The lat-lon pair's size follows from its resolution and the lenses' overlap, not from a
    pinhole's width and height: the budget is the designed pair's, and the advice when it does
    not fit names what sizes a lat-lon pair."""
    latlon = service_settings(small_recording.loop, tmp_path, lut_cache).model_copy(
        update={"rectified": RectifiedPairConfig(px_per_deg=4.0)}
    )
    runtime = Runtime.build(latlon)
    cam = runtime.pipeline.in_effect.camera
    assert runtime.pipeline.pair.projection == "latlon" and (cam.width, cam.height) != (640, 480)
    parts = runtime.memory_budget.parts
    assert parts["rectified_frames"] == FRAMES_ALIVE * 40 * cam.width * cam.height
    assert parts["lookup_tables"] == 2 * 15 * cam.width * cam.height
    finer = latlon.model_copy(update={"rectified": RectifiedPairConfig(px_per_deg=8.0)})
    monkeypatch.setattr(service.memory, "available_memory", lambda: 64 * MIB)
    with pytest.raises(SettingsError) as refused:
        Runtime.build(finer)
    message = str(refused.value)
    assert "lat-lon pair (8.000 px/deg)" in message and "a lower rectified.px_per_deg" in message
    assert "vpc.width" not in message and "rectified.width" not in message


def test_the_estimate_grows_with_what_it_estimates(small_recording: SmallRecording, tmp_path: Path) -> None:
    base = service_settings(small_recording.loop, tmp_path, tmp_path)
    rig = Runtime.build(base).rig
    pair = design_rectified_pair(rig, base.rectified)
    small = service_estimate(base, rig, pair, base.stereo)
    wide = design_rectified_pair(rig, base.rectified.model_copy(update={"width": 640, "height": 480}))
    assert (
        service_estimate(base, rig, wide, base.stereo).parts["rectified_frames"]
        == 4 * small.parts["rectified_frames"]
    )
    full = base.stereo.model_copy(update={"full_dp": True, "sgbm_mode": "hh"})
    # SGBM's full 8-path mode keeps the whole cost volume: 4 bytes per pixel and disparity.
    assert service_estimate(base, rig, pair, full).parts["matcher"] >= 4 * 320 * 240 * 64


def test_available_memory_reads_meminfo_and_the_cgroup_limit(tmp_path: Path) -> None:
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:  4000000 kB\nMemAvailable:  2000000 kB\n")
    group = tmp_path / "cgroup"
    group.mkdir()
    (group / "memory.max").write_text("max\n")
    (group / "memory.current").write_text("100\n")
    assert available_memory(meminfo, group) == 2_000_000 * 1024
    (group / "memory.max").write_text(f"{1024 * MIB}\n")
    (group / "memory.current").write_text(f"{256 * MIB}\n")
    assert available_memory(meminfo, group) == 768 * MIB
    assert available_memory(tmp_path / "none", tmp_path / "none") is None


def test_the_running_service_exports_its_budget(shared_app: InProcessServer) -> None:
    """(The resident size of ``rig serve`` against it: tests/reliability/test_load.py; this
    process holds the tests too.)"""
    metrics = shared_app.client.get("/metrics").text
    values = {
        line.split()[0]: float(line.split()[1])
        for line in metrics.splitlines()
        if line and not line.startswith("#")
    }
    assert values["rig_memory_budget_bytes"] == shared_app.runtime.memory_budget.total
