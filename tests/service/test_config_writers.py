"""Concurrent ``PATCH /config`` writers: every acknowledged change is in effect afterwards."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any

import httpx

from bench.hostile import FIELD_CHANGES
from tests.helpers.service import AUTH, StartApp


def _patch_all(client: httpx.Client, bodies: list[dict[str, Any]]) -> list[httpx.Response]:
    """All PATCHes at once, one thread each (concurrent calls of the app)."""

    def patch(stereo: dict[str, Any]) -> httpx.Response:
        return client.patch("/config", json={"stereo": stereo}, headers=AUTH, timeout=60)

    with ThreadPoolExecutor(len(bodies)) as pool:
        return list(pool.map(patch, bodies))


def _revision(response: httpx.Response) -> int:
    return int(response.headers["etag"].strip('"'))


def test_concurrent_writers_lose_no_update(start_app: StartApp) -> None:
    live = start_app()
    client = live.client
    first = client.get("/config")
    changes = [(f, v) for f, v in FIELD_CHANGES if first.json()["stereo"][f] != v]
    assert len(changes) >= 10

    # Writers of different fields: every acknowledged change is in the final state.
    replies = _patch_all(client, [{f: v} for f, v in changes])
    assert [r.status_code for r in replies] == [200] * len(changes), [r.text for r in replies]
    final = client.get("/config")
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
    replies = _patch_all(client, [{"speckle_size": v} for v in values])
    assert [r.status_code for r in replies] == [200] * len(values)
    last = max(zip((_revision(r) for r in replies), values, strict=True))[1]
    assert client.get("/config").json()["stereo"]["speckle_size"] == last
    assert live.runtime.pipeline.stereo.speckle_size == last


def test_if_match_applies_a_change_only_to_the_revision_it_names(start_app: StartApp) -> None:
    client = start_app().client
    read = client.get("/config")
    size = read.json()["stereo"]["speckle_size"]

    # Two clients read the same revision and both add 10 to speckle_size: one wins, one is told.
    first = client.patch(
        "/config",
        json={"stereo": {"speckle_size": size + 10}},
        headers={**AUTH, "If-Match": read.headers["etag"]},
    )
    second = client.patch(
        "/config",
        json={"stereo": {"speckle_size": size + 10}},
        headers={**AUTH, "If-Match": read.headers["etag"]},
    )
    assert first.status_code == 200 and _revision(first) == _revision(read) + 1
    assert second.status_code == 412, second.text
    assert f"revision {first.headers['etag']}" in second.json()["detail"]
    after = client.get("/config")
    assert after.json()["stereo"]["speckle_size"] == size + 10
    assert after.headers["etag"] == first.headers["etag"]  # the refused change made no revision

    # The current revision (or *) is accepted.
    again = client.patch(
        "/config",
        json={"stereo": {"speckle_size": size + 20}},
        headers={**AUTH, "If-Match": f'"0", {after.headers["etag"]}'},
    )
    assert again.status_code == 200 and again.json()["stereo"]["speckle_size"] == size + 20
    star = client.patch("/config", json={"stereo": {"speckle_size": size}}, headers={**AUTH, "If-Match": "*"})
    assert star.status_code == 200
