"""``/health`` does not grow with time: with a recording of thousands of files running, building
it makes as many file-system calls as with an empty one (counted, not timed)."""

from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Any

import pytest

from tests.helpers.service import AUTH, StartApp

FS_CALLS = ("stat", "lstat", "scandir", "listdir", "walk", "statvfs", "open")


def test_health_costs_the_same_with_3000_recorded_files(
    start_app: StartApp, monkeypatch: pytest.MonkeyPatch
) -> None:
    live = start_app()
    r = live.client.post("/recordings", json={"name": "long"}, headers=AUTH, timeout=30)
    assert r.status_code == 201, r.text
    recording = Path(r.json()["path"])
    me = threading.get_ident()
    calls = {"n": 0}
    for name in FS_CALLS:  # counted in this thread only (the worker and the writer run too)
        real = getattr(os, name)

        def counting(*args: Any, _real: Any = real, **kw: Any) -> Any:
            if threading.get_ident() == me:
                calls["n"] += 1
            return _real(*args, **kw)

        monkeypatch.setattr(os, name, counting)
    costs = []
    for files in (0, 3000):
        extra = recording / f"extra-{files}"  # stands for an hour of frames
        extra.mkdir()
        for k in range(files):
            (extra / f"{k:06d}.jpg").touch()
        calls["n"] = 0
        report = live.runtime.health()
        costs.append(calls["n"])
        assert report.recording is not None and report.recording.name == "long"
    assert costs[1] == costs[0], costs
    live.client.post("/recordings/long/stop", headers=AUTH, timeout=60)
