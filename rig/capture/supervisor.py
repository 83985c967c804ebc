"""One supervisor per camera: the capture thread, a watchdog, reconnects and the counters.

State machine: ``starting`` → ``available`` ⇄ ``unavailable(reason)`` → ``ended`` / ``stopped``,
logged once per change of (state, reason). The capture thread opens the camera, reads frames,
validates them (structure, and a decode of the luma per ``decode``), checks host-clock timestamps and hands
good frames to the sink. A separate watchdog thread marks the camera unavailable when no frame
has arrived for ``watchdog_s`` (OpenCV's ``read()`` can keep "succeeding" after an unplug, and a
blocked read cannot report anything) and asks for a reconnect after ``reconnect_after_s``.
Reconnects back off exponentially (``backoff_base_s`` doubling up to ``backoff_max_s``), re-open
the camera (which re-resolves by-path device links) and, after ``usb_reset_after`` failed
attempts in one outage, try ``camera.reset_hardware()`` (a USB reset) once. What it counts is
declared in :mod:`rig.counters` (group ``camera``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable

import cv2

from rig.capture.config import SupervisorConfig
from rig.capture.frame import Frame
from rig.capture.health import CameraHealth, CameraState
from rig.capture.protocol import Camera, CameraInfo
from rig.counters import Tally, complete
from rig.errors import CorruptFrameError, EndOfStream, RigError
from rig.priority import apply_to_current_thread

__all__ = ["CameraSupervisor"]

log = logging.getLogger("rig.capture")


class CameraSupervisor:
    """Runs ``camera`` in its own daemon thread and feeds valid frames to ``sink``."""

    def __init__(
        self,
        camera: Camera,
        config: SupervisorConfig,
        sink: Callable[[Frame], None],
        *,
        on_change: Callable[[], None] | None = None,
        consumer_waiting: Callable[[], bool] | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self.camera = camera
        self._consumer_waiting = consumer_waiting
        self.name = camera.name
        self.config = config
        self._sink = sink
        self._on_change = on_change
        self._clock = clock
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._state: CameraState = "starting"
        self._reason: str | None = None
        self.counters = Tally("camera")  # under self._lock
        self._last_frame_ns: int | None = None
        self._opened_ns: int | None = None
        self._last_seq: int | None = None
        self._last_ts: int | None = None
        self._last_error: tuple[str, int] | None = None
        self._arrivals: deque[int] = deque(maxlen=4096)
        self._reconnect = threading.Event()
        self._info: CameraInfo = camera.info()
        self._fresh_open = False

    # ----- lifecycle ---------------------------------------------------------------------------
    def start(self) -> None:
        if self._threads:
            return
        for target, suffix in ((self._run, "capture"), (self._watchdog, "watchdog")):
            t = threading.Thread(
                target=_prioritised, args=(target,), name=f"rig-{self.name}-{suffix}", daemon=True
            )
            self._threads.append(t)
            t.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop both threads and close the camera; idempotent."""
        self._stop.set()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout_s)
        if self.state[0] != "ended":
            self._transition("stopped", None)

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    @property
    def state(self) -> tuple[CameraState, str | None]:
        with self._lock:
            return self._state, self._reason

    def request_reconnect(self) -> None:
        self._reconnect.set()

    def report_undecodable(self, message: str) -> None:
        """A frame of this camera that passed the capture's checks did not decode when its
        consumer took it (with ``decode: false`` the capture thread checks only the structure):
        counted in ``frames_undecodable`` and kept as the last error, like a corrupt frame."""
        with self._lock:
            self.counters.add("frames_undecodable")
        self._error(message, unavailable=False)

    # ----- state -------------------------------------------------------------------------------
    def _transition(self, state: CameraState, reason: str | None, error: str | None = None) -> None:
        """Set the state (and the last error); logs once per change of (state, reason) and calls
        ``on_change`` outside the lock, so the callback may take other locks."""
        with self._lock:
            if error is not None:
                self._last_error = (error, self._clock())
            changed = (state, reason) != (self._state, self._reason)
            if changed:
                self._state, self._reason = state, reason
        if not changed:
            return
        if state == "unavailable":
            log.warning("camera %s unavailable: %s", self.name, reason)
        elif state == "available":
            log.info("camera %s available (%s)", self.name, self._info.device)
        else:
            log.info("camera %s %s%s", self.name, state, f": {reason}" if reason else "")
        if self._on_change is not None:
            self._on_change()

    def _error(self, message: str, *, unavailable: bool) -> None:
        if unavailable:
            self._transition("unavailable", message, error=message)
        else:
            with self._lock:
                self._last_error = (message, self._clock())

    def _watchdog_s(self) -> float:
        fps = self.camera.nominal_fps
        return max(self.config.watchdog_s, 3.0 / fps) if fps else self.config.watchdog_s

    # ----- threads -----------------------------------------------------------------------------
    def _watchdog(self) -> None:
        """Judges the camera's silence by the time the process ran. A tick that comes late by more
        than a period was held off with the whole process (on a starved machine, the GIL held
        by a thread the kernel does not run), and the capture thread with it; so the time beyond
        two periods is not the camera's: it is taken off the silence until the next frame."""
        last_tick, held_off, seen_ref = self._clock(), 0, 0
        while not self._stop.wait(period := min(0.05, self._watchdog_s() / 5)):
            limit = self._watchdog_s()
            now = self._clock()
            late, last_tick = now - last_tick - 2 * int(period * 1e9), now
            with self._lock:
                ref = max(self._last_frame_ns or 0, self._opened_ns or 0)
                if ref != seen_ref:
                    seen_ref, held_off = ref, 0
                held_off = min(held_off + max(0, late), now - ref)  # none of it before the frame
                age = (now - ref - held_off) / 1e9
                silent = bool(ref) and self._state == "available" and age > limit
                stalled = bool(ref) and self._state == "unavailable" and self._opened_ns is not None
            if silent:
                self._transition("unavailable", f"no frame for more than {limit:.2f} s")
            if stalled and age > self.config.reconnect_after_s:
                self._reconnect.set()

    def _backoff(self, attempt: int) -> float:
        c = self.config
        return float(min(c.backoff_max_s, c.backoff_base_s * 2 ** max(0, attempt - 1)))

    def _run(self) -> None:
        cam = self.camera
        opened = opened_before = reset_tried = False
        attempt = 0
        try:
            while not self._stop.is_set():
                if not opened:
                    if attempt and self._stop.wait(self._backoff(attempt)):
                        break
                    if opened_before:
                        with self._lock:
                            self.counters.add("reconnect_attempts")
                    try:
                        cam.open()
                    except EndOfStream as err:
                        self._end(str(err))
                        return
                    except Exception as err:  # RigError, or cv2.error/OSError from a driver: retry
                        attempt += 1
                        self._error(_describe(self.name, err), unavailable=True)
                        n = self.config.usb_reset_after
                        if n and attempt >= n and not reset_tried:
                            reset_tried = True
                            self._reset_hardware()
                        continue
                    with self._lock:
                        self._opened_ns = self._clock()
                        self._info = cam.info()
                        self._fresh_open = True
                        if opened_before:
                            self.counters.add("reconnects")
                    opened = opened_before = True
                    attempt, reset_tried = 0, False
                    self._reconnect.clear()
                if self._reconnect.is_set():
                    # Watchdog (stall) or a timestamp error: close, back off once, reopen.
                    self._reconnect.clear()
                    cam.close()
                    with self._lock:
                        self._opened_ns = None
                    opened, attempt = False, 1
                    continue
                asked = self._clock()
                try:
                    frame = cam.read(self.config.read_timeout_s)
                except EndOfStream as err:
                    self._end(str(err))
                    return
                except CorruptFrameError as err:
                    with self._lock:
                        self.counters.add("frames_corrupt")
                    self._error(str(err), unavailable=False)
                    continue
                except Exception as err:  # device gone (or a driver error): reopen at once, then back off
                    self._error(_describe(self.name, err), unavailable=True)
                    cam.close()
                    with self._lock:
                        self._opened_ns = None
                    opened, attempt = False, 0
                    continue
                if frame is not None:
                    self._accept(frame, asked)
        finally:
            cam.close()

    def _end(self, reason: str) -> None:
        self.camera.close()
        self._transition("ended", reason)

    def _reset_hardware(self) -> None:
        try:
            what = self.camera.reset_hardware()
        except RigError as err:
            log.warning("camera %s: reset failed: %s", self.name, err)
            return
        with self._lock:
            self.counters.add("usb_resets")
        log.warning("camera %s: %s", self.name, what)

    def _accept(self, frame: Frame, asked_ns: int) -> None:
        now = self._clock()
        with self._lock:
            if self._fresh_open:
                # Some cameras settle their timestamp source on the first frame after open.
                self._info = self.camera.info()
                self._fresh_open = False
            if self._last_seq is not None and frame.seq > self._last_seq + 1:
                gap = frame.seq - self._last_seq - 1
                self.counters.add("frames_lost", gap)
                # Reported, not a state change: a camera dropping frames (or at half rate) still works.
                self._last_error = (f"camera {self.name}: {gap} frame(s) lost before seq {frame.seq}", now)
            self._last_seq = frame.seq
        try:
            frame.check_structure()
            if self._decode_here():
                frame.gray  # noqa: B018 - decode (the luma depth needs) once here, cached for the consumer
        except CorruptFrameError as err:
            with self._lock:
                self.counters.add("frames_corrupt")
            self._error(str(err), unavailable=False)
            return
        problem = self._timestamp_problem(frame, now - asked_ns)
        if problem:
            with self._lock:
                self.counters.add("timestamp_errors")
                self._last_ts = None  # the reconnect re-validates the clock
            self._error(f"camera {self.name}: {problem}", unavailable=True)
            self._reconnect.set()
            return
        with self._lock:
            self._last_ts = frame.ts_ns
            self._last_frame_ns = now
            self._arrivals.append(now)
            self.counters.add("frames_received")
        self._transition("available", None)
        self._sink(frame)

    def _decode_here(self) -> bool:
        """Whether this thread decodes the frame (``decode``): ``auto`` does while the consumer
        waits for a pair, which it will take, so the decode costs it nothing; a consumer that is
        busy skips most frames, and decodes only those it takes itself. Without a consumer to
        ask, ``auto`` decodes every frame."""
        mode = self.config.decode
        if mode == "auto":
            return self._consumer_waiting is None or self._consumer_waiting()
        return bool(mode)

    def _timestamp_problem(self, frame: Frame, read_ns: int) -> str | None:
        """A capture time cannot lie after the frame's arrival (same clock), nor long before the
        read that took it was asked for: the read's own time (``read_ns``, the capture thread's
        clock) is not held against the camera, since a process held off inside the read (a
        starved machine) stamps the frame's arrival late without any fault of its clock."""
        if not self._info.host_clock:
            return None
        offset_ms = (frame.ts_ns - frame.host_ns) / 1e6
        if offset_ms > self.config.max_future_ms:
            return f"timestamp {offset_ms / 1e3:.3f} s ahead of the host clock (clock jump)"
        before_ask_ms = -offset_ms - max(0, read_ns) / 1e6
        if before_ask_ms > self.config.max_clock_offset_ms:
            return f"timestamp {-offset_ms / 1e3:.3f} s behind the host clock (clock jump or stale frame)"
        if self._last_ts is not None and frame.ts_ns <= self._last_ts:
            return f"timestamp went back {(self._last_ts - frame.ts_ns) / 1e6:.1f} ms"
        return None

    # ----- health ------------------------------------------------------------------------------
    def health(self) -> CameraHealth:
        """Snapshot of this camera (pairing's counters, 0 here, and the rates over the window,
        None here, are filled in by StereoCapture)."""
        now = self._clock()
        window = round(self.config.fps_window_s * 1e9)
        with self._lock:
            recent = [t for t in self._arrivals if now - t <= window]
            fps = (len(recent) - 1) / ((recent[-1] - recent[0]) / 1e9) if len(recent) > 1 else 0.0
            if recent and recent[-1] - recent[0] <= 0:
                fps = 0.0
            age = None if self._last_frame_ns is None else (now - self._last_frame_ns) / 1e6
            err, err_age = (None, None)
            if self._last_error is not None:
                err, err_age = self._last_error[0], (now - self._last_error[1]) / 1e6
            info = self._info
            counters = {
                **self.counters.snapshot(),
                "connected": self._state == "available",
                "fps": fps,
                "last_frame_age_ms": age,
                # Rates over the window and pairing's drops are StereoCapture's (rig.capture.rates).
                "corrupt_per_s": None,
                "undecodable_per_s": None,
                "dropped_per_s": None,
            }
            return CameraHealth(
                name=self.name,
                kind=self.camera.kind,
                device=info.device,
                state=self._state,
                reason=self._reason,
                nominal_fps=self.camera.nominal_fps,
                last_seq=self._last_seq,
                last_ts_ns=self._last_ts,
                timestamp_source=info.timestamp_source,
                timestamp_note=info.timestamp_note,
                last_error=err,
                last_error_age_ms=err_age,
                format=info.format,
                width=info.width,
                height=info.height,
                degraded_reason=None,
                counters=complete("camera", counters),
            )


def _prioritised(target: Callable[[], None]) -> None:
    apply_to_current_thread()  # the depth threads' priority (rig.priority)
    target()


def _describe(camera: str, err: Exception) -> str:
    """Our errors carry their own message; anything else (cv2.error, OSError) gets named."""
    if isinstance(err, RigError):
        return str(err)
    kind = "OpenCV error" if isinstance(err, cv2.error) else type(err).__name__
    return f"camera {camera}: {kind}: {' '.join(str(err).split())}"
