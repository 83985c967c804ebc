"""Pairing by nearest timestamps: deterministic synthetic streams with jitter, drops, gaps."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.capture.capture import default_skew_gate_ns
from rig.capture.frame import Frame
from rig.capture.pairing import FramePairer

PERIOD = 33_333_333
GATE = PERIOD // 2


def frame(cam: str, seq: int, ts: int) -> Frame:
    return Frame(cam, seq, ts, "jpeg", host_ns=0, raw=b"\xff\xd8\xff\xd9")


def stream(cam: str, seqs: list[int], jitter: dict[int, int] | None = None) -> list[Frame]:
    jitter = jitter or {}
    return [frame(cam, k, 1_000_000_000 + k * PERIOD + jitter.get(k, 0)) for k in seqs]


def run(pairer: FramePairer, order: list[Frame]) -> list[tuple[int, int]]:
    out = []
    for f in order:
        out += [(p.left.seq, p.right.seq) for p in pairer.push(f)]
    return out


def interleave(left: list[Frame], right: list[Frame], choices: list[bool]) -> list[Frame]:
    """Merge two per-camera streams in the order ``choices`` dictates (True = take left next)."""
    li = ri = 0
    out = []
    it = iter(choices)
    while li < len(left) or ri < len(right):
        take_left = ri >= len(right) or (li < len(left) and next(it, True))
        if take_left:
            out.append(left[li])
            li += 1
        else:
            out.append(right[ri])
            ri += 1
    return out


def test_default_gate_is_half_the_faster_period() -> None:
    assert default_skew_gate_ns([30.0, 30.0]) == round(0.5e9 / 30)
    assert default_skew_gate_ns([15.0, 60.0]) == round(0.5e9 / 60)
    assert default_skew_gate_ns([None, None]) == round(0.5e9 / 30)


def test_jittered_streams_pair_frame_for_frame_and_skew_stats_match_numpy() -> None:
    rng = np.random.default_rng(7)
    n = 200
    jl = {k: int(v) for k, v in enumerate(rng.uniform(-6e6, 6e6, n))}
    jr = {k: int(v) for k, v in enumerate(rng.uniform(-6e6, 6e6, n))}
    left, right = stream("left", list(range(n)), jl), stream("right", list(range(n)), jr)
    pairer = FramePairer(GATE, buffer_size=n, skew_window=n)
    pairs = run(pairer, interleave(left, right, list(rng.random(2 * n) < 0.5)))
    assert pairs == [(k, k) for k in range(n)]
    skews_ms = np.abs([jl[k] - jr[k] for k in range(n)]) / 1e6
    p50, p95 = pairer.skew_percentiles_ms()
    assert p50 == pytest.approx(np.percentile(skews_ms, 50), abs=1e-6)
    assert p95 == pytest.approx(np.percentile(skews_ms, 95), abs=1e-6)
    c = pairer.counts()
    assert c.unpaired == {"left": 0, "right": 0} and c.pairs_formed == n


def test_skew_window_slides() -> None:
    pairer = FramePairer(GATE, skew_window=3)
    for k, skew in enumerate([10_000_000, 10_000_000, 1_000_000, 1_000_000, 1_000_000]):
        pairer.push(frame("left", k, k * PERIOD + skew))
        pairer.push(frame("right", k, k * PERIOD))
    assert pairer.skew_samples == 3
    assert pairer.skew_percentiles_ms() == (pytest.approx(1.0), pytest.approx(1.0))


def test_drops_pair_only_frames_present_in_both_and_count_the_rest() -> None:
    n = 100
    rng = np.random.default_rng(3)
    lseq = [k for k in range(n) if rng.random() > 0.15]
    rseq = [k for k in range(n) if rng.random() > 0.15]
    pairer = FramePairer(GATE, buffer_size=50)
    pairs = run(
        pairer, interleave(stream("left", lseq), stream("right", rseq), list(rng.random(2 * n) < 0.5))
    )
    both = sorted(set(lseq) & set(rseq))
    # The last frame of each camera may still wait for a partner that would arrive next.
    assert pairs == [(k, k) for k in both]
    c = pairer.counts()
    assert c.unpaired["left"] + c.buffered["left"] == len(lseq) - len(both)
    assert c.unpaired["right"] + c.buffered["right"] == len(rseq) - len(both)


def test_never_pairs_across_a_gap() -> None:
    # Left lost frames 3..5; right's 3..5 must not pair with left's 6 (one period or more away).
    pairer = FramePairer(GATE)
    left = stream("left", [0, 1, 2, 6, 7])
    right = stream("right", [0, 1, 2, 3, 4, 5, 6, 7])
    assert run(pairer, left + right) == [(0, 0), (1, 1), (2, 2), (6, 6), (7, 7)]
    assert pairer.counts().unpaired == {"left": 0, "right": 3}


def test_skew_gate_is_inclusive_and_strict_beyond() -> None:
    pairer = FramePairer(GATE)
    assert run(pairer, [frame("left", 0, 1_000 + GATE), frame("right", 0, 1_000)]) == [(0, 0)]
    pairer = FramePairer(GATE)
    assert run(pairer, [frame("left", 0, 1_000 + GATE + 1), frame("right", 0, 1_000)]) == []
    assert pairer.counts().unpaired == {"left": 0, "right": 1}


def test_bounded_buffer_drops_oldest() -> None:
    pairer = FramePairer(GATE, buffer_size=8)
    run(pairer, stream("left", list(range(20))))
    c = pairer.counts()
    assert c.evicted["left"] == 12 and c.buffered["left"] == 8
    # The survivors are the newest: a right frame 12 pairs with left 12.
    assert run(pairer, [frame("right", 12, 1_000_000_000 + 12 * PERIOD)]) == [(12, 12)]


def test_wide_gate_prefers_the_nearest_buffered_partner() -> None:
    pairer = FramePairer(gate_ns=PERIOD)  # wider than half a period: two candidates possible
    left = [frame("left", 0, 0), frame("left", 1, PERIOD)]
    right = [frame("right", 1, PERIOD - 1_000_000)]
    assert run(pairer, left + right) == [(1, 1)]
    assert pairer.counts().unpaired["left"] == 1


def test_end_and_exhausted() -> None:
    pairer = FramePairer(GATE)
    run(pairer, stream("left", [0, 1]))
    pairer.end("left")
    assert not pairer.exhausted  # left frames still wait for right partners
    run(pairer, stream("right", [0, 1]))
    assert pairer.exhausted


def test_rejects_bad_parameters() -> None:
    with pytest.raises(ValueError):
        FramePairer(0)
    with pytest.raises(ValueError):
        FramePairer(GATE, names=("a",))


@settings(max_examples=60, deadline=None)
@given(
    lkeep=st.lists(st.booleans(), min_size=40, max_size=40),
    rkeep=st.lists(st.booleans(), min_size=40, max_size=40),
    choices=st.lists(st.booleans(), min_size=80, max_size=80),
    jitter=st.lists(st.integers(-5_000_000, 5_000_000), min_size=80, max_size=80),
)
def test_pairs_do_not_depend_on_arrival_order(
    lkeep: list[bool], rkeep: list[bool], choices: list[bool], jitter: list[int]
) -> None:
    lseq = [k for k in range(40) if lkeep[k]]
    rseq = [k for k in range(40) if rkeep[k]]
    left = stream("left", lseq, {k: jitter[k] for k in range(40)})
    right = stream("right", rseq, {k: jitter[40 + k] for k in range(40)})
    reference = run(FramePairer(GATE, buffer_size=100), left + right)
    shuffled = run(FramePairer(GATE, buffer_size=100), interleave(left, right, choices))
    assert shuffled == reference
    both = sorted(set(lseq) & set(rseq))
    # With |jitter| <= 5 ms the last common frame may still wait; everything before it paired.
    assert reference == [(k, k) for k in both][: len(reference)]
    assert len(reference) >= len(both) - 1
