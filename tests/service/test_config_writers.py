"""Concurrent ``PATCH /config`` writers: every acknowledged change is in effect afterwards."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any

import httpx

from bench.hostile import FIELD_CHANGES
from tests.helpers.service import AUTH, StartServer


def _patch_all(base: str, bodies: list[dict[str, Any]]) -> list[httpx.Response]:
    """All PATCHes at once, one thread and connection each."""

    def patch(stereo: dict[str, Any]) -> httpx.Response:
        return httpx.patch(base + "/config", json={"stereo": stereo}, headers=AUTH, timeout=60)

    with ThreadPoolExecutor(len(bodies)) as pool:
        return list(pool.map(patch, bodies))


def _revision(response: httpx.Response) -> int:
    return int(response.headers["etag"].strip('"'))


def test_concurrent_writers_lose_no_update(start_server: StartServer) -> None:
    live = start_server()
    base = live.base_url
    first = httpx.get(base + "/config")
    changes = [(f, v) for f, v in FIELD_CHANGES if first.json()["stereo"][f] != v]
    assert len(changes) >= 10

    # Writers of different fields: every acknowledged change is in the final state.
    replies = _patch_all(base, [{f: v} for f, v in changes])
    assert [r.status_code for r in replies] == [200] * len(changes), [r.text for r in replies]
    final = httpx.get(base + "/config")
    lost = [f for f, v in changes if final.json()["stereo"][f] != v]
    assert lost == []
    start = _revision(first)
    # One revision per change, in one order; each answer holds its own change.
    assert sorted(_revision(r) for r in replies) == list(range(start + 1, start + 1 + len(changes)))
    assert _revision(final) == start + len(changes)
    for (f, v), r in zip(changes, replies, strict=True):
        assert r.json()["stereo"][f] == v
    # In effect: the pipeline the worker matches with holds them.
    assert live.runtime.pipeline.stereo.model_dump() == final.json()["stereo"]

    # Writers of one field: the final value is the last write in the server's order.
    values = [200 + k for k in range(12)]
    replies = _patch_all(base, [{"speckle_size": v} for v in values])
    assert [r.status_code for r in replies] == [200] * len(values)
    last = max(zip((_revision(r) for r in replies), values, strict=True))[1]
    assert httpx.get(base + "/config").json()["stereo"]["speckle_size"] == last
    assert live.runtime.pipeline.stereo.speckle_size == last
