"""MCAP files in ROS 2's profile (``ros2msg`` schemas, ``cdr`` messages), written atomically.

:class:`McapRosWriter` writes to ``NAME.partial`` beside the final name and renames it into place
only when the file is complete (summary, footer, fsync), so a crash never leaves a half file under
the final name. Channels carry ``offered_qos_profiles`` (``/tf_static`` transient-local, so a late
subscriber of ``ros2 bag play`` still gets it), and the file ends with the ``rosbag2`` metadata
record ``ros2 bag`` writes (the bag's ``metadata.yaml`` content), so ``ros2 bag info`` and
``ros2 bag play`` read it like their own recordings.

``durable=True`` (recordings) makes every chunk reach the kernel as soon as it is written and
closes the chunk in progress every ``flush_interval_s``: a killed process loses at most that
chunk. What the ``.partial`` file holds is read back by :func:`recover_mcap`, which writes the
recovered file through :func:`calibration.atomic.atomic_file`. The ``.partial`` file itself is
not one of that function's temporaries: it is written for the whole of a recording, has a name
the user is told (to recover it, or to refuse a second recording over it) and is kept, not
removed, when the writer dies.
"""

from __future__ import annotations

import contextlib
import errno
import os
import struct
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from importlib.metadata import version
from pathlib import Path
from typing import IO, Literal

import yaml
from mcap.exceptions import McapError
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2.metadata import dump_qos_v8

from calibration.atomic import atomic_file, fsync_directory
from rig.errors import DiskFullError, RecordingError
from rig.ros import cdr
from rig.ros.messages import Message as RigMessage

__all__ = ["Compression", "McapRosWriter", "RecoverResult", "partial_path", "recover_mcap"]

Compression = Literal["zstd", "lz4", "none"]
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
_NO_SPACE = {errno.ENOSPC, errno.EDQUOT}
_ZERO = QosTime(0, 0)
#: rosbag2's metadata version whose QoS profiles are integers (Iron); Humble ignores the record.
_BAG_VERSION = 8


def partial_path(path: Path) -> Path:
    """Where :class:`McapRosWriter` writes ``path`` until it is complete."""
    return path.with_name(path.name + ".partial")


def _qos_yaml(topic: str) -> str:
    latched = topic.endswith("/tf_static")
    qos = Qos(
        QosHistory.KEEP_LAST,
        1 if latched else 10,
        QosReliability.RELIABLE,
        QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE,
        _ZERO,
        _ZERO,
        QosLiveliness.AUTOMATIC,
        _ZERO,
        False,
    )
    return dump_qos_v8([qos])


def _library() -> str:
    return f"odfc-rig/{version('odfc-rig')}; mcap/{version('mcap')}; rosbags/{version('rosbags')}"


def _translate(err: OSError, path: Path, keep: bool = False) -> RecordingError:
    """The error of a failed write; ``keep``: the partial file stays, say how to recover it."""
    hint = f"; what was written is recovered with `rig record --recover {path}`" if keep else ""
    if err.errno in _NO_SPACE:
        return DiskFullError(f"{path}: disk full; the MCAP file stopped ({err.strerror}){hint}")
    return RecordingError(f"{path}: cannot write MCAP ({err.strerror or err}){hint}")


class McapRosWriter:
    """Writes :mod:`rig.ros.messages` messages into ``path`` (see the module docstring).

    ``exist_ok``: replace an existing ``path`` (export) or refuse (recordings). An existing
    ``.partial`` file is always refused: it may be a recording cut short, to recover first.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        compression: Compression = "zstd",
        chunk_size: int = 4 * 1024 * 1024,
        durable: bool = False,
        flush_interval_s: float = 1.0,
        fsync: bool = False,
        exist_ok: bool = True,
    ) -> None:
        self.path = Path(path)
        self.partial = partial_path(self.path)
        self.durable = durable
        self.flush_interval_s = flush_interval_s
        self.fsync = fsync
        if not exist_ok and self.path.exists():
            raise RecordingError(f"{self.path}: already exists")
        try:
            self._file: IO[bytes] | None = open(self.partial, "xb")  # noqa: SIM115
        except FileExistsError:
            raise RecordingError(
                f"{self.partial}: exists (an MCAP file cut short?): recover it with "
                f"`rig record --recover {self.partial}` or remove it"
            ) from None
        except OSError as err:
            raise _translate(err, self.partial) from err
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=_COMPRESSION[compression])
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self._counts: dict[str, int] = {}
        self._first_ns: int | None = None
        self._last_ns = 0
        self._last_flush = time.monotonic()
        self.messages = 0
        self._guard(lambda: self._writer.start(profile="ros2", library=_library()))

    def __enter__(self) -> McapRosWriter:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    # ----- writing -----------------------------------------------------------------------------
    def _guard(self, step: Callable[[], object]) -> None:
        try:
            step()
        except OSError as err:
            raise _translate(err, self.partial, keep=self.durable) from err

    def _channel(self, topic: str, typename: str) -> int:
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != typename:
                raise RecordingError(f"{self.path}: topic {topic} carries {known[1]}, not {typename}")
            return known[0]
        schema = self._schemas.get(typename)
        if schema is None:
            schema = self._writer.register_schema(typename, "ros2msg", cdr.msgdef(typename).encode())
            self._schemas[typename] = schema
        channel = self._writer.register_channel(
            topic, "cdr", schema, metadata={"offered_qos_profiles": _qos_yaml(topic)}
        )
        self._channels[topic] = (channel, typename)
        self._counts[topic] = 0
        return channel

    def write(self, message: RigMessage, log_time_ns: int | None = None, sequence: int = 0) -> None:
        """One message, logged at ``log_time_ns`` (default: its header stamp)."""
        if self._file is None:
            raise RecordingError(f"{self.path}: MCAP writer already closed")
        t = message.stamp_ns if log_time_ns is None else int(log_time_ns)
        channel = self._channel(message.topic, cdr.ros_type(message))
        data = cdr.serialize(message)
        self._guard(
            lambda: self._writer.add_message(
                channel, log_time=t, data=data, publish_time=t, sequence=sequence
            )
        )
        self._counts[message.topic] += 1
        self.messages += 1
        self._first_ns = t if self._first_ns is None else min(self._first_ns, t)
        self._last_ns = max(self._last_ns, t)

    def write_all(self, messages: Iterable[RigMessage], sequence: int = 0) -> None:
        """Several messages, then (``durable``) the flushes that keep them safe."""
        for m in messages:
            self.write(m, sequence=sequence)
        if self.durable:
            self.flush(force=time.monotonic() - self._last_flush >= self.flush_interval_s)

    def flush(self, *, force: bool = True) -> None:
        """Hand finished chunks to the kernel; ``force`` also closes the chunk in progress (and
        with ``fsync`` forces the file to the device)."""
        file = self._file
        if file is None:
            return

        def step() -> None:
            if force:
                _call(self._writer.flush)
                self._last_flush = time.monotonic()
                if self.fsync:
                    os.fsync(file.fileno())
            else:
                file.flush()

        self._guard(step)

    # ----- finishing ---------------------------------------------------------------------------
    def _bag_metadata(self) -> str:
        start = self._first_ns or 0
        duration = max(0, self._last_ns - start)
        topics = [
            {
                "topic_metadata": {
                    "name": topic,
                    "type": typename,
                    "serialization_format": "cdr",
                    "offered_qos_profiles": _qos_yaml(topic),
                    "type_description_hash": "",
                },
                "message_count": self._counts[topic],
            }
            for topic, (_, typename) in self._channels.items()
        ]
        info = {
            "version": _BAG_VERSION,
            "storage_identifier": "mcap",
            "relative_file_paths": [self.path.name],
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": self.messages,
            "topics_with_message_count": topics,
            "compression_format": "",
            "compression_mode": "",
            "files": [
                {
                    "path": self.path.name,
                    "starting_time": {"nanoseconds_since_epoch": start},
                    "duration": {"nanoseconds": duration},
                    "message_count": self.messages,
                }
            ],
            "custom_data": None,
            "ros_distro": "humble",
        }
        return yaml.safe_dump(info, sort_keys=False).strip()

    def close(self) -> Path:
        """Finish the file (summary, footer), fsync it and rename it to its final name."""
        file = self._file
        if file is None:
            return self.path

        def finish() -> None:
            self._writer.add_metadata("rosbag2", {"serialized_metadata": self._bag_metadata()})
            _call(self._writer.finish)
            file.flush()
            os.fsync(file.fileno())

        try:
            self._guard(finish)
        finally:
            self._file = None
            file.close()
        try:
            os.replace(self.partial, self.path)
        except OSError as err:
            raise _translate(err, self.path) from err
        fsync_directory(self.path.parent)
        return self.path

    def abort(self, *, keep: bool = False) -> None:
        """Stop without finishing; the partial file is removed unless ``keep`` (a recording
        keeps what it has written, for :func:`recover_mcap`)."""
        file, self._file = self._file, None
        if file is not None:
            with contextlib.suppress(OSError):
                file.close()
        if not keep:
            self.partial.unlink(missing_ok=True)


def _call(method: Callable[[], object]) -> None:
    """Call one of mcap's unannotated methods (typed here, for mypy's strict mode)."""
    method()


@dataclass(frozen=True)
class RecoverResult:
    path: Path
    messages: int
    complete: bool


def recover_mcap(partial: str | Path, out: str | Path | None = None) -> RecoverResult:
    """Rewrite what a cut-short MCAP file holds (every complete chunk) as a complete file at
    ``out`` (default: the name without ``.partial``), atomically, streaming; the partial file
    is removed once the new one is in place. ``complete`` tells whether the input had its footer."""
    src = Path(partial)
    dst = Path(out) if out is not None else src.with_name(src.name.removesuffix(".partial"))
    if dst == src:
        raise RecordingError(f"{src}: give an output name (the input does not end in .partial)")
    if dst.exists():
        raise RecordingError(f"{dst}: already exists; give another output name")
    try:
        with open(src, "rb") as f_in, atomic_file(dst) as f_out:
            kept, complete = _copy_records(f_in, Writer(f_out))
    except OSError as err:
        raise _translate(err, dst) from err
    except RecordingError as err:
        raise RecordingError(f"{src}: {err}") from None
    fsync_directory(dst.parent)
    src.unlink(missing_ok=True)
    return RecoverResult(dst, kept, complete)


def _copy_records(source: IO[bytes], writer: Writer) -> tuple[int, bool]:
    """Schemas, channels and messages of ``source`` up to where it is cut, into ``writer``
    (finished); (messages kept, whether the source was complete)."""
    writer.start(profile="ros2", library=_library())
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    kept = 0
    complete = False
    try:
        for record in StreamReader(source, validate_crcs=True).records:
            if isinstance(record, Schema):
                schema_ids[record.id] = writer.register_schema(record.name, record.encoding, record.data)
            elif isinstance(record, Channel):
                schema = schema_ids.get(record.schema_id, 0)
                channel_ids[record.id] = writer.register_channel(
                    record.topic, record.message_encoding, schema, record.metadata
                )
            elif isinstance(record, Message) and record.channel_id in channel_ids:
                cid = channel_ids[record.channel_id]
                writer.add_message(cid, record.log_time, record.data, record.publish_time, record.sequence)
                kept += 1
        complete = True
    except (McapError, ValueError, EOFError, struct.error):
        pass  # the cut: keep what came before
    if not channel_ids:
        raise RecordingError("holds no complete MCAP chunk; nothing to recover")
    _call(writer.finish)
    return kept, complete
