"""`rig record`: record synchronised pairs from the cameras (sets of N frames from a rig of N
cameras, the config's ``cameras.rig``), or re-record a recording (see docs/cameras.md)."""

from __future__ import annotations

import contextlib
import signal
import threading
from pathlib import Path
from types import FrameType
from typing import Annotated, Any, Literal

import typer

from cli.console import console, err_console, progress_bar
from cli.errors import fail
from rig.capture.capture import RigCapture
from rig.capture.config import CaptureConfig, load_capture_config
from rig.capture.health import CaptureHealth
from rig.capture.recorder import Recorder, RecordResult, copy_calibration, replay_capture_config
from rig.errors import DiskFullError, RigError
from rig.recording import PairWriter, Recording, RecordingWriter
from rig.ros.mcap_export import McapRecordingWriter
from rig.ros.mcap_writer import partial_path, recover_mcap

__all__ = ["register"]


def _summary(out: Path, result_pairs: int, stopped_by: str, health: CaptureHealth) -> str:
    cams = health.cameras
    dropped = ", ".join(f"{n} {c.counters['frames_dropped']}" for n, c in cams.items())
    corrupt = ", ".join(f"{n} {c.counters['frames_corrupt']}" for n, c in cams.items())
    p = health.pairing.counters
    p50, p95 = p["skew_ms"], p["skew_ms_p95"]
    skew = f"; skew p50 {p50:.2f} ms, p95 {p95:.2f} ms" if p50 is not None and p95 is not None else ""
    late = f"; pairs dropped (writer too slow): {p['pairs_evicted']}" if p["pairs_evicted"] else ""
    return (
        f"recorded {result_pairs} pairs to {out} (stopped: {stopped_by}); "
        f"frames dropped: {dropped}; corrupt: {corrupt}{skew}{late}"
    )


class _StopOnSignal:
    """SIGINT/SIGTERM set a flag (the loop then flushes, closes and reports) instead of killing."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self._old: dict[int, Any] = {}

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        self.event.set()

    def __enter__(self) -> _StopOnSignal:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)


def _recover(recover: Path, out: Path | None, *, excluded: bool) -> None:
    """``--recover``: the complete chunks of an MCAP recording cut short, as a complete file."""
    if excluded:
        fail("--recover excludes --config and --replay")
    recovered = recover_mcap(recover, out)
    state = "complete" if recovered.complete else "cut short"
    console.print(
        f"recovered {recovered.messages} messages from {recover} ({state}) -> {recovered.path}",
        highlight=False,
        soft_wrap=True,
    )


def _replay_source(
    replay: Path, frames: int | None, seconds: float | None
) -> tuple[CaptureConfig, Recording, dict[str, Any], float | None]:
    """The capture config replaying ``replay``, that recording, the new recording's metadata
    and the number of pairs to expect (None: unknown)."""
    capture_cfg, source_rec = replay_capture_config(replay)
    meta: dict[str, Any] = {"created_by": "rig record", "source": {"replay": str(replay)}}
    total: float | None = frames or (None if seconds else len(source_rec.pairs))
    return capture_cfg, source_rec, meta, total


def _config_source(config: Path) -> tuple[CaptureConfig, dict[str, Any]]:
    """The capture config of the config file ``config`` and the new recording's metadata."""
    loaded = load_capture_config(config)
    # Recording stores bytes; decoding in the capture threads would only cost CPU.
    capture_cfg = loaded.model_copy(
        update={"supervisor": loaded.supervisor.model_copy(update={"decode": False})}
    )
    return capture_cfg, {"created_by": "rig record", "source": {"config": str(config)}}


def _refuse_existing(out: Path, format: str) -> None:
    """Refuse to write over a recording: an MCAP file (or its partial file), or a recording
    directory's frames.csv."""
    if format == "mcap":
        for path in (out, partial_path(out)):
            if path.exists():
                fail(f"{path}: already exists" + (" (recover it with --recover)" if path != out else ""))
    elif (out / "frames.csv").exists():
        fail(f"{out}: already holds a recording (frames.csv exists)")


def register(app: typer.Typer) -> None:
    @app.command(
        "record",
        help="Record synchronised frame pairs from the cameras of a config file (--config), or "
        "re-record a recording (--replay), into a recording directory or an MCAP file (--format mcap); "
        "--recover FILE.partial finishes an MCAP recording cut short.",
    )
    def record(
        out: Annotated[
            Path | None,
            typer.Option("--out", metavar="PATH", help="Recording directory, or MCAP file, to create."),
        ] = None,
        config: Annotated[
            Path | None,
            typer.Option("--config", metavar="FILE", help="YAML file with a 'cameras:' section."),
        ] = None,
        replay: Annotated[
            Path | None, typer.Option("--replay", metavar="DIR", help="Recording directory to replay.")
        ] = None,
        seconds: Annotated[
            float | None, typer.Option("--seconds", metavar="SECONDS", min=0.0, help="Stop after this long.")
        ] = None,
        frames: Annotated[
            int | None, typer.Option("--frames", metavar="N", min=1, help="Stop after this many pairs.")
        ] = None,
        fsync: Annotated[
            bool, typer.Option("--fsync", help="fsync every pair (survives power loss).")
        ] = False,
        startup_timeout: Annotated[
            float,
            typer.Option(
                "--startup-timeout",
                metavar="SECONDS",
                min=0.0,
                help="Fail if a camera gives no pair by then.",
            ),
        ] = 10.0,
        format: Annotated[
            Literal["dir", "mcap"],
            typer.Option(
                "--format",
                metavar="FORMAT",
                help="dir: a recording directory; mcap: an MCAP file in ROS 2's profile (docs/ros.md).",
            ),
        ] = "dir",
        recover: Annotated[
            Path | None,
            typer.Option(
                "--recover",
                metavar="FILE",
                help="Write the complete chunks of an MCAP recording cut short as a complete file.",
            ),
        ] = None,
    ) -> None:
        if recover is not None:
            _recover(recover, out, excluded=config is not None or replay is not None)
            return
        if out is None:
            fail("--out PATH is required")
        if (config is None) == (replay is None):
            fail("give exactly one of --config FILE or --replay RECORDING")
        if seconds is not None and frames is not None:
            fail("give at most one of --seconds and --frames")
        if replay is not None:
            capture_cfg, source_rec, meta, total = _replay_source(replay, frames, seconds)
        else:
            assert config is not None
            capture_cfg, meta = _config_source(config)
            source_rec, total = None, frames
        meta["capture"] = capture_cfg.model_dump(mode="json")
        _refuse_existing(out, format)

        def open_writer() -> PairWriter:
            if format == "mcap":
                return McapRecordingWriter(out, cameras=capture_cfg.names, fsync=fsync)
            writer = RecordingWriter(out, meta=meta, cameras=capture_cfg.names, fsync=fsync)
            if source_rec is not None:
                copy_calibration(source_rec, out)
            return writer

        capture = RigCapture(capture_cfg)
        recorder = Recorder(capture, open_writer)
        progress = progress_bar(disable=not err_console.is_terminal)
        task = progress.add_task("recording pairs", total=total)
        result: RecordResult | None = None
        try:
            with _StopOnSignal() as stop, progress:
                capture.start()
                result = recorder.run(
                    max_pairs=frames,
                    max_seconds=seconds,
                    should_stop=stop.event.is_set,
                    on_pair=lambda n: progress.update(task, completed=n),
                    startup_timeout_s=startup_timeout,
                )
        except DiskFullError as err:
            capture.stop()
            with contextlib.suppress(RigError):  # an MCAP file cannot be finished either: it stays partial
                recorder.close()
            where = f", {out} stays readable" if format == "dir" else ""
            raise DiskFullError(f"{err} ({recorder.written} pairs written{where})") from err
        finally:
            capture.stop()
            recorder.close()
        assert result is not None
        recorder.complete()
        console.print(
            _summary(out, result.pairs_written, result.stopped_by, capture.health()),
            highlight=False,
            soft_wrap=True,
        )
