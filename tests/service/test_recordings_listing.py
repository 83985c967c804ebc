"""``GET /recordings`` over a recordings directory holding what crashes and careless hands leave:
a malformed ``recording.json`` is named in its entry's ``error`` instead of making every listing a
500, and a recording that was never stopped is listed from its index, not by walking its frames
(file-system calls counted, not timed)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import httpx
import pytest

from service.recordings import RecordingManager
from tests.helpers.service import StartServer

BAD_META: dict[str, bytes] = {
    "not-json": b"{not json",
    "a-list": b"[1, 2]",
    "not-utf8": b'{"pairs": 3, "note": "\xff\xfe"}',
    "text-count": b'{"pairs": 3, "bytes": 10, "dropped": "x"}',
    "number-time": b'{"pairs": 3, "bytes": 10, "started_at": 5}',
    "odd-counts": b'{"pairs": -3, "bytes": 1.5, "error": {"nested": true}}',
}


def crashed_recording(root: Path, name: str, pairs: int, extra_files: int = 0) -> Path:
    """A recording as a crash leaves it: recording.json without the counts of a stop, an index
    of ``pairs`` pairs and ``extra_files`` more frame files."""
    path = root / name
    (path / "frames").mkdir(parents=True)
    (path / "recording.json").write_text(json.dumps({"cameras": ["left", "right"], "started_at": "t0"}))
    rows = ["seq,left_ts_ns,right_ts_ns,left_file,right_file"]
    rows += [f"{k},{k * 1000},{k * 1000},frames/{k}_l.png,frames/{k}_r.png" for k in range(pairs)]
    (path / "frames.csv").write_text("\n".join(rows) + "\n")
    for k in range(extra_files):
        (path / "frames" / f"{k:06d}.jpg").touch()
    return path


def test_malformed_recording_json_is_named_not_a_500(start_server: StartServer) -> None:
    live = start_server()
    root = Path(live.settings.server.recordings_dir)
    root.mkdir(parents=True, exist_ok=True)
    for name, meta in BAD_META.items():
        (root / name).mkdir()
        (root / name / "recording.json").write_bytes(meta)
    crashed_recording(root, "crashed", 4)
    r = httpx.get(live.base_url + "/recordings", timeout=30)
    assert r.status_code == 200, r.text
    listing = {e["name"]: e for e in r.json()}
    assert set(listing) == {*BAD_META, "crashed"}
    for name in ("not-json", "a-list", "not-utf8"):
        assert f"{name}/recording.json: " in listing[name]["error"], listing[name]
    assert "field 'dropped' must be a count" in listing["text-count"]["error"]
    assert listing["text-count"]["pairs"] == 3 and listing["text-count"]["dropped"] == 0
    assert "field 'started_at' must be text" in listing["number-time"]["error"]
    odd = listing["odd-counts"]["error"]
    assert all(f"field '{f}'" in odd for f in ("pairs", "bytes", "error")), odd
    assert listing["crashed"]["pairs"] == 4 and listing["crashed"]["bytes"] is None
    assert listing["crashed"]["error"] is None


FS_CALLS = ("stat", "lstat", "scandir", "listdir", "walk", "open")


def test_listing_a_crashed_recording_does_not_walk_its_frames(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls = {"n": 0}
    for name in FS_CALLS:
        real = getattr(os, name)

        def counting(*args: Any, _real: Any = real, **kw: Any) -> Any:
            calls["n"] += 1
            return _real(*args, **kw)

        monkeypatch.setattr(os, name, counting)
    costs, listed = [], []
    for files in (0, 3000):
        mgr = RecordingManager(tmp_path / str(files))
        crashed_recording(mgr.root, "crashed", 3, files)
        mgr.list()  # the first listing of an index reads it
        calls["n"] = 0
        listed += mgr.list()
        costs.append(calls["n"])
    assert costs[1] == costs[0], costs
    assert [(e.pairs, e.bytes) for e in listed] == [(3, None), (3, None)]
