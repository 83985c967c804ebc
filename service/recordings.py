"""Recordings made by the running service: the raw camera frames of the pairs the worker takes.

``start(name)`` opens a :class:`~rig.recording.RecordingWriter` under ``recordings_dir/name``
(with the rig's ``calibration.yaml``, so ``rig serve --recording`` replays it) and a writer
thread; the worker hands every pair to :meth:`RecordingManager.offer`, which never blocks: a
full queue drops the pair and counts it (``dropped`` in the listing). Frames are stored as the
cameras delivered them (MJPEG byte-exact, PNG for rendered replays; decoded-only frames as
lossless PNG). ``stop(name)`` drains the queue, closes the files and writes the stop time and
counts into ``recording.json``.

Names match :data:`NAME_PATTERN` (no separators, no ``..``) and are resolved under
``recordings_dir`` and checked again after resolution, so no name can leave it.
"""

from __future__ import annotations

import errno
import json
import logging
import queue
import re
import shutil
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from calibration import save_rig
from calibration.atomic import write_atomic
from calibration.rig import Rig
from rig.capture.frame import FrameSet
from rig.capture.recorder import store_set
from rig.errors import DiskFullError, RecordingError, RigError
from rig.priority import apply_to_current_thread
from rig.recording import RecordingWriter
from service.errors import RecordingConflict, RecordingNameError, RecordingNotFound, RecordingStorageError

__all__ = ["NAME_PATTERN", "RecordingManager", "RecordingStatus", "recording_path", "validate_name"]

log = logging.getLogger("service.recordings")

#: 1-64 of A-Z a-z 0-9 . _ -, first a letter or digit, no ".." (ECMA/Python regex, lookahead).
NAME_PATTERN = r"^(?!.*\.\.)[A-Za-z0-9][A-Za-z0-9._-]{0,63}$"
_NAME_RE = re.compile(NAME_PATTERN)
_STOP = object()


def validate_name(name: str) -> str:
    if not isinstance(name, str) or not _NAME_RE.fullmatch(name) or ".." in name:
        raise RecordingNameError(
            f"invalid recording name {name!r}: 1-64 characters of A-Z a-z 0-9 . _ -, "
            "starting with a letter or digit, without '..'"
        )
    return name


def recording_path(root: Path, name: str) -> Path:
    """``root/name`` after validation, checked to lie directly inside ``root`` once resolved."""
    validate_name(name)
    base = root.expanduser().resolve()
    path = (base / name).resolve()
    if path.parent != base:
        raise RecordingNameError(f"invalid recording name {name!r}: resolves outside {base}")
    return path


def _now_iso() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


@dataclass(frozen=True)
class RecordingStatus:
    name: str
    path: str
    active: bool
    pairs: int
    bytes: int | None  # None: not noted (a recording not stopped cleanly; the listing walks no files)
    dropped: int
    started_at: str | None
    stopped_at: str | None
    error: str | None


class _Active:
    def __init__(self, name: str, path: Path, writer: RecordingWriter, queue_size: int) -> None:
        self.name = name
        self.path = path
        self.writer = writer
        self.queue: queue.Queue[Any] = queue.Queue(maxsize=queue_size)
        self.started_at = _now_iso()
        self.dropped = 0
        self.extra_bytes = 0  # files besides the writer's (calibration.yaml)
        self.error: str | None = None
        self.last_seq: int | None = None
        self.thread = threading.Thread(target=self._run, name=f"rig-recording-{name}", daemon=True)

    def _run(self) -> None:
        apply_to_current_thread()  # a recorded frame is never lost to HTTP clients' CPU
        while True:
            item = self.queue.get()
            if item is _STOP:
                return
            if self.error is not None:
                continue  # failed: drain without writing
            try:
                self._write(item)
            except RigError as err:
                self.error = str(err)
                log.error("recording %s stopped writing: %s", self.name, err)

    def _write(self, pair: FrameSet) -> None:
        if self.last_seq is not None and pair.seq <= self.last_seq:
            raise RecordingError(
                f"{self.path}: {pair.cameras[0]} camera seq went from {self.last_seq} back to {pair.seq} "
                "(a looping replay with recorded timestamps; use timestamps: live)"
            )
        store_set(self.writer, pair)
        self.last_seq = pair.seq


def _count(value: Any) -> int | None:
    """``value`` if it is a count (an int ≥ 0), else None."""
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 0 else None


def _recorded_bytes(path: Path, data_bytes: int) -> int:
    """``data_bytes`` (all files but recording.json) and recording.json's size."""
    try:
        return data_bytes + (path / "recording.json").stat().st_size
    except OSError:
        return data_bytes


_COUNTS = ("pairs", "bytes", "dropped")
_TEXTS = ("started_at", "stopped_at", "error")


def _noted(path: Path) -> tuple[dict[str, Any], list[str]]:
    """The fields a stopped recording noted in its recording.json, each checked (a wrong one is
    left out), and what is wrong with the file."""
    meta = path / "recording.json"
    try:
        doc = json.loads(meta.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        return {}, [f"{meta}: unreadable ({type(err).__name__}: {str(err)[:80]})"]
    if not isinstance(doc, dict):
        return {}, [f"{meta}: not a JSON object"]
    noted: dict[str, Any] = {}
    problems = []
    for key in (*_COUNTS, *_TEXTS):
        value = doc.get(key)
        ok = _count(value) is not None if key in _COUNTS else isinstance(value, str)
        if ok:
            noted[key] = value
        elif value is not None:
            kind = "a count" if key in _COUNTS else "text"
            problems.append(f"{meta}: field '{key}' must be {kind}, got {json.dumps(value)[:40]}")
    return noted, problems


class _PairCounts:
    """Pairs in each frames.csv, counted once per version of the file (a recording that was not
    stopped cleanly noted no count; 100 000 pairs are 6 MB of index to read)."""

    def __init__(self) -> None:
        self._known: dict[Path, tuple[int, int, int]] = {}
        self._lock = threading.Lock()

    def __call__(self, path: Path) -> int:
        index = path / "frames.csv"
        try:
            st = index.stat()
            with self._lock:
                known = self._known.get(index)
            if known is not None and known[:2] == (st.st_mtime_ns, st.st_size):
                return known[2]
            with open(index, "rb") as f:
                lines = sum(1 for line in f if line.strip())
        except OSError:
            return 0
        count = max(0, lines - 1)
        with self._lock:
            self._known[index] = (st.st_mtime_ns, st.st_size, count)
        return count


class RecordingManager:
    """Starts, feeds, stops and lists recordings under ``root`` (see module doc). Thread-safe."""

    def __init__(
        self,
        root: Path,
        *,
        queue_size: int = 64,
        rig: Rig | None = None,
        cameras: Sequence[str] = ("left", "right"),
    ) -> None:
        self.root = root.expanduser()
        self.queue_size = queue_size
        self.rig = rig
        self.cameras = list(cameras)
        self._lock = threading.Lock()
        self._active: _Active | None = None
        self._pair_counts = _PairCounts()

    def start(self, name: str, meta: dict[str, Any] | None = None) -> RecordingStatus:
        """Start recording into ``root/name``. A recording that cannot start leaves nothing
        behind (its name stays free): RecordingConflict, RecordingStorageError for a
        recordings directory that cannot hold it, DiskFullError, RecordingError."""
        path = recording_path(self.root, name)
        with self._lock:
            if self._active is not None:
                raise RecordingConflict(f"recording {self._active.name!r} is running; stop it first")
            if path.exists():
                raise RecordingConflict(f"recording {name!r} already exists in {self.root}")
            self._make_root()
            try:
                path.mkdir()
            except FileExistsError:
                raise RecordingConflict(f"recording {name!r} already exists in {self.root}") from None
            except OSError as err:
                raise self._storage_error(err) from err
            try:
                active = self._open(name, path, meta)
            except BaseException:
                shutil.rmtree(path, ignore_errors=True)
                raise
            self._active = active
            log.info("recording %s started in %s", name, path)
            return self._status_of(active)

    def _make_root(self) -> None:
        try:
            self.root.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise self._storage_error(err) from err

    def _storage_error(self, err: OSError) -> DiskFullError | RecordingStorageError:
        if err.errno in (errno.ENOSPC, errno.EDQUOT):
            return DiskFullError(f"server.recordings_dir {self.root}: disk full")
        reason = "not a directory" if isinstance(err, FileExistsError | NotADirectoryError) else err.strerror
        return RecordingStorageError(
            f"server.recordings_dir {self.root}: cannot hold recordings ({reason or err})"
        )

    def _open(self, name: str, path: Path, meta: dict[str, Any] | None) -> _Active:
        doc = {"source": "rig serve", "name": name, "started_at": _now_iso(), **(meta or {})}
        writer = RecordingWriter(path, meta=doc, cameras=self.cameras)
        active = _Active(name, path, writer, self.queue_size)
        active.started_at = doc["started_at"]
        if self.rig is not None:
            calibration = path / "calibration.yaml"
            try:
                save_rig(self.rig, calibration)
                active.extra_bytes = calibration.stat().st_size
            except Exception as err:  # the frames matter more than the calibration copy
                log.warning("recording %s: calibration not saved: %s", name, err)
        active.thread.start()
        return active

    def offer(self, pair: FrameSet) -> None:
        """Queue a pair (a set) for the running recording (if any); never blocks, counts drops."""
        active = self._active
        if active is None:
            return
        try:
            active.queue.put_nowait(pair)
        except queue.Full:
            active.dropped += 1

    def stop(self, name: str) -> RecordingStatus:
        validate_name(name)
        with self._lock:
            active = self._active
            if active is None or active.name != name:
                running = f"; running: {active.name!r}" if active is not None else "; none is running"
                raise RecordingNotFound(f"recording {name!r} is not running{running}")
            self._active = None
        return self._close(active)

    def close(self) -> None:
        """Stop the running recording, if any (service shutdown)."""
        with self._lock:
            active, self._active = self._active, None
        if active is not None:
            self._close(active)

    def _close(self, active: _Active) -> RecordingStatus:
        active.queue.put(_STOP)  # blocks only while the writer drains a full queue
        active.thread.join()
        try:
            active.writer.close()
        except RigError as err:
            active.error = active.error or str(err)
        stopped = _now_iso()
        meta_path = active.path / "recording.json"
        try:
            doc = json.loads(meta_path.read_text(encoding="utf-8"))
            # "bytes": everything but recording.json itself (see list()).
            data_bytes = active.writer.data_bytes + active.extra_bytes
            doc.update(
                stopped_at=stopped,
                pairs=active.writer.count,
                bytes=data_bytes,
                dropped=active.dropped,
                error=active.error,
            )
            write_atomic(meta_path, (json.dumps(doc, indent=2) + "\n").encode())
        except (OSError, ValueError) as err:
            log.warning("recording %s: could not note the stop in recording.json: %s", active.name, err)
        log.info(
            "recording %s stopped: %d pairs, %d dropped", active.name, active.writer.count, active.dropped
        )
        return self._status_of(active, stopped_at=stopped)

    def _status_of(self, active: _Active, stopped_at: str | None = None) -> RecordingStatus:
        """The status of ``active``: still running, or just stopped at ``stopped_at``."""
        if stopped_at is None:
            size = active.writer.bytes_written + active.extra_bytes  # counted: no walk (/health)
        else:
            size = _recorded_bytes(active.path, active.writer.data_bytes + active.extra_bytes)
        return RecordingStatus(
            name=active.name,
            path=str(active.path),
            active=stopped_at is None,
            pairs=active.writer.count,
            bytes=size,
            dropped=active.dropped,
            started_at=active.started_at,
            stopped_at=stopped_at,
            error=active.error,
        )

    @property
    def active(self) -> RecordingStatus | None:
        active = self._active
        return None if active is None else self._status_of(active)

    def list(self) -> list[RecordingStatus]:
        """Every recording directory under ``root`` (those with a recording.json), by name. What
        a recording noted at its stop is read from its recording.json, never from its frames: a
        recording that was not stopped cleanly has its pairs counted from its index and no
        ``bytes``. A recording.json that cannot be read, or a field of the wrong kind, is named
        in the entry's ``error`` instead of failing the listing."""
        active = self._active
        out: list[RecordingStatus] = []
        if not self.root.is_dir():
            return out
        for path in sorted(p for p in self.root.iterdir() if (p / "recording.json").is_file()):
            if active is not None and path.name == active.name:
                out.append(self._status_of(active))
                continue
            out.append(self._stored_status(path))
        return out

    def _stored_status(self, path: Path) -> RecordingStatus:
        noted, problems = _noted(path)
        pairs, size = noted.get("pairs"), noted.get("bytes")
        errors = [noted["error"]] if "error" in noted else []
        return RecordingStatus(
            name=path.name,
            path=str(path),
            active=False,
            pairs=pairs if pairs is not None else self._pair_counts(path),
            bytes=_recorded_bytes(path, size) if size is not None else None,
            dropped=noted.get("dropped", 0),
            started_at=noted.get("started_at"),
            stopped_at=noted.get("stopped_at"),
            error="; ".join(errors + problems) or None,
        )
