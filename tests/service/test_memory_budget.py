"""The memory budget: estimated from the settings before anything is built, a size that cannot fit
refused at start-up with its reason, a tight one warned about, the budget exported."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

import service.memory
from rig.memory_budget import MIB, available_memory
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
        update={"vpc": settings.vpc.model_copy(update={"width": 4096, "height": 3072})}
    )
    monkeypatch.setattr(service.memory, "available_memory", lambda: 1024 * MIB)  # a 1 GiB board
    with pytest.raises(SettingsError) as refused:
        Runtime.build(huge)
    message = str(refused.value)
    assert "field 'vpc': a 4096x3072 VPC with 64 disparities needs about" in message
    assert "more than the 1024 MiB this machine has left" in message and "vpc frames" in message
    assert not cache.exists() or not any(cache.iterdir())  # no table was built


def test_a_tight_budget_is_warned_about(
    small_recording: SmallRecording, tmp_path: Path, lut_cache: Path, caplog: pytest.LogCaptureFixture
) -> None:
    settings = service_settings(small_recording.loop, tmp_path, lut_cache)
    runtime = Runtime.build(settings)
    estimate = runtime.memory_budget
    with caplog.at_level(logging.WARNING, logger="service.memory"):
        service.memory.check_memory(settings, estimate, available=int(estimate.total / 0.9))
    assert "needs about" in caplog.text and "320x240 VPC" in caplog.text
    caplog.clear()
    service.memory.check_memory(settings, estimate, available=4 * estimate.total)
    assert caplog.text == ""


def test_the_estimate_grows_with_what_it_estimates(
    small_recording: SmallRecording, tmp_path: Path, lut_cache: Path
) -> None:
    base = service_settings(small_recording.loop, tmp_path, lut_cache)
    rig = Runtime.build(base).rig
    small = service_estimate(base, rig)
    wide = base.model_copy(update={"vpc": base.vpc.model_copy(update={"width": 640, "height": 480})})
    assert service_estimate(wide, rig).parts["rect_frames"] == 4 * small.parts["rect_frames"]
    full = base.model_copy(
        update={"stereo": base.stereo.model_copy(update={"full_dp": True, "sgbm_mode": "hh"})}
    )
    # SGBM's full 8-path mode keeps the whole cost volume: 4 bytes per pixel and disparity.
    assert service_estimate(full, rig).parts["matcher"] >= 4 * 320 * 240 * 64


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
