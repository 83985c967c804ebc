"""ROS bags (MCAP, ROS 2 ``.db3`` or bag directories, ROS 1 ``.bag``) as recordings: two image
topics paired by header stamp (or N, one per camera of a rig, in synchronised sets), read through
``rosbags`` (no ROS installation).

:class:`BagRecording` has the reading surface of :class:`~rig.recording.Recording` (``root``,
``cameras``, ``pairs``, :meth:`read_frame`), so a bag goes wherever a recording directory goes:
``rig process``, the export, and the file cameras of ``rig serve`` (through the same camera,
supervisor and pairing code as a recording directory).

Pairing: both topics' header stamps, sorted; a left and a right message pair when each is the
other's nearest and they lie within the skew gate (default half the median frame period). With N
topics a set is a message of the first topic and, of every other, its nearest message that has it
as its own nearest, all within the gate of each other. When fewer than half the messages of the
sparsest topic find a set, the topics are not synchronised and the bag is refused, with the
figures. ``CompressedImage`` frames keep their
bytes (JPEG or PNG); raw ``Image`` frames are decoded to gray or BGR (16-bit scaled to 8).
"""

from __future__ import annotations

import bisect
import itertools
import statistics
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rig.errors import RecordingError
from rig.recording import FrameSetRecord, PairRecord, StoredFrame
from rig.ros.images import decode_raw_image

if TYPE_CHECKING:  # rosbags loads when a bag is opened, not for every command that reads recordings
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection

__all__ = ["BAG_SUFFIXES", "BagRecording", "is_bag", "match_stamps", "pair_stamps"]

BAG_SUFFIXES = (".mcap", ".db3", ".bag")
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
_DEFAULT_PERIOD_NS = 33_333_333


def is_bag(path: Path) -> bool:
    """A bag file by its suffix, or a ROS 2 bag directory (``metadata.yaml``)."""
    return path.suffix.lower() in BAG_SUFFIXES or (path.is_dir() and (path / "metadata.yaml").is_file())


def _reader_errors() -> tuple[type[Exception], ...]:
    """What a bag reader raises on a file it cannot read (rosbags' own error among them)."""
    from rosbags.highlevel import AnyReaderError

    return (AnyReaderError, OSError, ValueError, KeyError, AssertionError)


def _stamp_ns(message: Any) -> int:
    stamp = message.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


@dataclass(frozen=True)
class _Entry:
    stamp_ns: int
    log_ns: int


def _nearest(values: list[int], t: int) -> int:
    """Index of the value of sorted ``values`` nearest to ``t`` (the earlier one on a tie)."""
    k = bisect.bisect_left(values, t)
    if k == 0:
        return 0
    if k == len(values) or t - values[k - 1] <= values[k] - t:
        return k - 1
    return k


def pair_stamps(left: list[int], right: list[int], gate_ns: int) -> list[tuple[int, int]]:
    """Indices (i, j) of ``left[i]``, ``right[j]`` (both sorted) that are each other's nearest
    stamp and within ``gate_ns``."""

    out = []
    for i, t in enumerate(left):
        j = _nearest(right, t)
        if abs(right[j] - t) <= gate_ns and _nearest(left, right[j]) == i:
            out.append((i, j))
    return out


def match_stamps(stamps: list[list[int]], gate_ns: int) -> list[tuple[int, ...]]:
    """Indices, one per topic, of the sets of ``stamps`` (each topic's, sorted; the first is the
    reference): each other topic's message is the reference's nearest and has it as its nearest,
    and the set's stamps lie within ``gate_ns`` of each other. Two topics: :func:`pair_stamps`."""
    first, others = stamps[0], stamps[1:]
    out = []
    for i, t in enumerate(first):
        chosen = [i]
        for other in others:
            j = _nearest(other, t)
            if _nearest(first, other[j]) != i:
                break
            chosen.append(j)
        else:
            set_stamps = [s[k] for s, k in zip(stamps, chosen, strict=True)]
            if max(set_stamps) - min(set_stamps) <= gate_ns:
                out.append(tuple(chosen))
    return out


def _median_period(stamps: list[int]) -> int:
    steps = [b - a for a, b in itertools.pairwise(stamps) if b > a]
    return int(statistics.median(steps)) if steps else _DEFAULT_PERIOD_NS


class BagRecording:
    """Two image topics of a bag as a recording of ``left``/``right`` pairs, or ``topics`` (camera
    → topic, N of them) as a recording of those cameras' sets (module docstring).
    ``max_skew_ns``: the pairing gate (default half the first topic's median period)."""

    def __init__(
        self,
        path: str | Path,
        left_topic: str | None = None,
        right_topic: str | None = None,
        *,
        topics: dict[str, str] | None = None,
        max_skew_ns: int | None = None,
    ) -> None:
        self.root = Path(path)
        if topics is None:
            if left_topic is None or right_topic is None:
                raise RecordingError(
                    f"{self.root}: a bag needs its image topics (left and right, or per camera)"
                )
            topics = {"left": left_topic, "right": right_topic}
        if len(topics) < 2:
            raise RecordingError(f"{self.root}: a bag recording needs two image topics or more, got {topics}")
        self.cameras = list(topics)
        self.topics = dict(topics)
        self.calibration_path: Path | None = None
        self.truncated_tail = False
        self.meta: dict[str, Any] = {"bag": str(self.root), "topics": dict(self.topics)}
        self._local = threading.local()
        self._readers: list[AnyReader] = []
        self._lock = threading.Lock()
        if not self.root.exists():
            raise RecordingError(f"{self.root}: not found")
        reader = self._reader()
        self.connections = {cam: self._connections(reader, cam) for cam in self.cameras}
        entries = self._index(reader)
        self.pairs, self._entries = self._pair(entries, max_skew_ns)

    # ----- opening -----------------------------------------------------------------------------
    def _reader(self) -> AnyReader:
        """This thread's open reader (one per thread: readers keep a file position)."""
        reader: AnyReader | None = getattr(self._local, "reader", None)
        if reader is None:
            from rosbags.highlevel import AnyReader

            try:
                reader = AnyReader([self.root])
                reader.open()
            except _reader_errors() as err:
                raise RecordingError(_describe_open_error(self.root, err)) from None
            self._local.reader = reader
            with self._lock:
                self._readers.append(reader)
        return reader

    def _connections(self, reader: AnyReader, cam: str) -> list[Connection]:
        topic = self.topics[cam]
        conns = [c for c in reader.connections if c.topic == topic]
        images = sorted({c.topic for c in reader.connections if c.msgtype in IMAGE_TYPES})
        if not conns:
            have = ", ".join(images) if images else "none"
            raise RecordingError(
                f"{self.root}: no topic {topic!r} ({cam} camera); image topics in the bag: {have}"
            )
        wrong = [c.msgtype for c in conns if c.msgtype not in IMAGE_TYPES]
        if wrong:
            raise RecordingError(
                f"{self.root}: topic {topic!r} carries {wrong[0]}, "
                "not sensor_msgs/msg/Image or sensor_msgs/msg/CompressedImage"
            )
        return conns

    def _index(self, reader: AnyReader) -> dict[str, list[_Entry]]:
        by_id = {c.id: cam for cam, conns in self.connections.items() for c in conns}
        out: dict[str, list[_Entry]] = {cam: [] for cam in self.cameras}
        try:
            for conn, log_ns, raw in reader.messages(
                connections=[c for cs in self.connections.values() for c in cs]
            ):
                msg = reader.deserialize(raw, conn.msgtype)
                out[by_id[conn.id]].append(_Entry(_stamp_ns(msg), int(log_ns)))
        except _reader_errors() as err:
            raise RecordingError(_describe_open_error(self.root, err)) from None
        for cam, entries in out.items():
            if not entries:
                raise RecordingError(f"{self.root}: topic {self.topics[cam]!r} holds no messages")
            entries.sort(key=lambda e: e.stamp_ns)
        return out

    def _pair(
        self, entries: dict[str, list[_Entry]], max_skew_ns: int | None
    ) -> tuple[list[PairRecord], dict[str, list[_Entry]]]:
        stamps = [[e.stamp_ns for e in entries[c]] for c in self.cameras]
        gate = max_skew_ns if max_skew_ns is not None else _median_period(stamps[0]) // 2
        matches = match_stamps(stamps, gate)
        fewest = min(len(s) for s in stamps)
        if len(matches) * 2 < fewest:
            first = stamps[0]
            offsets = [statistics.median(abs(o[_nearest(o, t)] - t) for t in first) / 1e6 for o in stamps[1:]]
            names = " and ".join(repr(self.topics[c]) for c in self.cameras)
            raise RecordingError(
                f"{self.root}: topics {names} are not synchronised: {len(matches)} of {fewest} messages "
                f"have a partner within ±{gate / 1e6:.1f} ms of header stamp (median offset "
                f"{max(offsets):.1f} ms)"
            )
        pairs = []
        kept: dict[str, list[_Entry]] = {c: [] for c in self.cameras}
        for seq, chosen in enumerate(matches):
            for c, k in zip(self.cameras, chosen, strict=True):
                kept[c].append(entries[c][k])
            set_stamps = {c: s[k] for c, s, k in zip(self.cameras, stamps, chosen, strict=True)}
            files = {c: f"{self.topics[c]}@{t}" for c, t in set_stamps.items()}
            pairs.append(FrameSetRecord.of(seq, set_stamps, files))
        return pairs, kept

    # ----- reading -----------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.pairs)

    def __iter__(self) -> Iterator[PairRecord]:
        return iter(self.pairs)

    def read_frame(self, pair: PairRecord, camera: str) -> StoredFrame:
        """The frame of ``camera`` in ``pair``: compressed bytes as stored, raw images decoded."""
        entry = self._entries[camera][pair.seq]
        source = f"{self.root}:{pair.file(camera)}"
        reader = self._reader()
        conns = self.connections[camera]
        try:
            for conn, _, raw in reader.messages(connections=conns, start=entry.log_ns, stop=entry.log_ns + 1):
                msg = reader.deserialize(raw, conn.msgtype)
                if _stamp_ns(msg) == entry.stamp_ns:
                    return _stored(msg, conn.msgtype, source)
        except _reader_errors() as err:
            raise RecordingError(f"{source}: unreadable ({err})") from None
        raise RecordingError(f"{source}: message not found")

    def close(self) -> None:
        with self._lock:
            readers, self._readers = self._readers, []
        for r in readers:
            r.close()
        self._local = threading.local()


def _stored(msg: Any, msgtype: str, source: str) -> StoredFrame:
    if msgtype.endswith("CompressedImage"):
        fmt = str(msg.format).lower()
        kind = "png" if "png" in fmt else "jpeg" if ("jpeg" in fmt or "jpg" in fmt) else None
        if kind is None or "compresseddepth" in fmt:
            raise RecordingError(
                f"{source}: compressed image format {msg.format!r} is not read (jpeg or png)"
            )
        return StoredFrame(kind, raw=bytes(msg.data), source=source)
    try:
        img = decode_raw_image(
            msg.encoding, msg.width, msg.height, msg.step, msg.data, bool(msg.is_bigendian)
        )
    except ValueError as err:
        raise RecordingError(f"{source}: {err}") from None
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    return StoredFrame("bgr", image=img, source=source)


def _describe_open_error(path: Path, err: Exception) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    if "magic" in text.lower() or "truncat" in text.lower() or isinstance(err, (EOFError, AssertionError)):
        return (
            f"{path}: truncated or corrupt bag ({text}); "
            "an MCAP recording cut short is recovered with `rig record --recover`"
        )
    return f"{path}: not a readable bag ({text})"
