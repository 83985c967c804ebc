"""The counter table (rig.counters): consistent, enforced on every snapshot, and documented in
docs/counters.md exactly as declared."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import rig.counters
from rig.counters import COUNTERS, GROUPS, CounterSpec, Tally, complete, counters_of, markdown

DOC = Path(__file__).resolve().parents[2] / "docs" / "counters.md"


def _spec(name: str, group: str = "camera", kind: str = "counter", **more: object) -> CounterSpec:
    return CounterSpec(name, group, kind, "frames", "test", **more)  # type: ignore[arg-type]


def test_the_table_holds_each_group_with_unique_names_and_metrics() -> None:
    for group in GROUPS:
        names = [c.name for c in counters_of(group)]
        assert names and len(names) == len(set(names))
    assert sum(len(counters_of(g)) for g in GROUPS) == len(COUNTERS)
    # The names the tests, dashboards and alerts already use stay as they were.
    samples = {c.metric_selector for c in COUNTERS}
    assert {
        "rig_camera_connected",
        "rig_camera_fps",
        "rig_camera_frames_dropped_total",
        "rig_camera_reconnects_total",
        "rig_camera_last_frame_age_seconds",
        'rig_pairing_skew_ms{quantile="0.5"}',
        'rig_pairing_skew_ms{quantile="0.95"}',
        "rig_pairs_formed_total",
        "rig_pairs_skipped_total",
        "rig_worker_frames_total",
        "rig_worker_result_age_ms",
    } <= samples


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (_spec("frames_received"), "declared twice"),
        (_spec("frames_x", value=float), "non-null integer"),
        (_spec("frames_x", sum_of=("fps",)), "not a plain counter"),
        (_spec("frames_x", sum_of=("frames_dropped",)), "not a plain counter"),
        (_spec("frames_x", metric="rig_camera_fps"), "shared by counters of another"),
        (_spec("x", group="pairing", kind="gauge", metric="rig_pairing_skew_ms"), "shared by counters"),
        (
            _spec(
                "x",
                group="pairing",
                kind="gauge",
                metric="rig_pairing_skew_ms",
                metric_labels=(("quantile", "0.5"),),
            ),
            "shared by counters",
        ),
    ],
)
def test_a_table_the_code_cannot_derive_from_is_refused(
    monkeypatch: pytest.MonkeyPatch, extra: CounterSpec, words: str
) -> None:
    monkeypatch.setattr(rig.counters, "COUNTERS", (*COUNTERS, extra))
    with pytest.raises(ValueError, match=words):
        counters_of("camera")


def test_complete_sums_derived_counters_and_refuses_anything_undeclared() -> None:
    measured = {**Tally("camera").snapshot(), "connected": True, "fps": 2.5, "last_frame_age_ms": None}
    measured.update(corrupt_per_s=None, undecodable_per_s=0.5, dropped_per_s=1.0)
    measured.update(frames_lost=3, frames_unpaired=4, frames_evicted=5, frames_dropped=999)
    out = complete("camera", measured)
    assert list(out) == [c.name for c in counters_of("camera")]
    assert out["frames_dropped"] == 12  # recomputed from its parts, whatever it was
    assert out["fps"] == 2.5 and out["last_frame_age_ms"] is None
    with pytest.raises(KeyError, match="not declared"):
        complete("camera", {**measured, "frames_bogus": 1})
    del measured["fps"]
    with pytest.raises(KeyError, match=r"camera\.fps declared in rig.counters but not measured"):
        complete("camera", measured)


def test_a_tally_counts_the_plain_counters_of_its_group_only() -> None:
    tally = Tally("camera")
    plain = {c.name for c in counters_of("camera") if c.kind == "counter" and not c.sum_of}
    assert set(tally.snapshot()) == plain and set(tally.snapshot().values()) == {0}
    tally.add("frames_lost", 3)
    tally.add("frames_lost")
    assert tally["frames_lost"] == 4
    for name in ("frames_dropped", "fps", "frames_bogus"):  # derived, a gauge, undeclared
        with pytest.raises(KeyError):
            tally.add(name)


def test_an_added_counter_is_tallied_and_must_be_measured(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(rig.counters, "COUNTERS", (*COUNTERS, _spec("frames_new"), _spec("q", kind="gauge")))
    tally = Tally("camera")
    tally.add("frames_new", 2)
    measured = {**tally.snapshot(), "connected": True, "fps": 1.0, "last_frame_age_ms": 5.0}
    measured.update(corrupt_per_s=None, undecodable_per_s=None, dropped_per_s=None)
    with pytest.raises(KeyError, match=r"camera\.q declared"):
        complete("camera", measured)
    assert complete("camera", {**measured, "q": 7.0})["frames_new"] == 2


def test_docs_counters_md_is_the_generated_table() -> None:
    text = DOC.read_text(encoding="utf-8")
    assert text == markdown(), "docs/counters.md is stale: python -m rig.counters > docs/counters.md"
    # Independently of markdown(): each group's section lists exactly the group's names, in order.
    sections = re.split(r"^## ", text, flags=re.M)[1:]
    assert len(sections) == len(GROUPS)
    for group, section in zip(GROUPS, sections, strict=True):
        rows = re.findall(r"^\| `(\w+)` \| (counter|gauge) \| ([^|]+) \|", section, flags=re.M)
        assert [(n, k, u.strip()) for n, k, u in rows] == [
            (c.name, c.kind, c.unit) for c in counters_of(group)
        ]
