"""The capture the service and ``rig record`` use: supervised cameras → synchronised sets (pairs
for two cameras).

``RigCapture(config).start()`` runs one supervisor (capture + watchdog thread) per camera of the
config (``left`` and ``right``, or a rig's N cameras); each valid frame goes through
:class:`~rig.capture.pairing.FramePairer` under one lock, and complete sets wait in a bounded
buffer. ``next_set()`` hands out the newest set not yet taken (older ones are counted as skipped)
or, with ``newest=False``, the oldest (recording); ``next_pair()`` is the same for two cameras.
:data:`StereoCapture` is its name where two cameras are meant (the service, ``rig record``).

All buffers are bounded and drop their oldest entry when full; with
``pairing.backpressure`` the camera threads wait for room instead (file replays, where waiting
costs nothing and every frame must be kept).

Each camera's frame-loss rates over ``supervisor.rate_window_s`` (:mod:`rig.capture.rates`) are
sampled by every :meth:`health` call and twice a second by a monitor thread, so a camera that
starts losing frames is logged once (warning) and its recovery once (info) whether or not
anyone polls the health.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import replace

from rig.capture.config import CaptureConfig, V4L2CameraConfig
from rig.capture.factory import open_camera
from rig.capture.faults import Fault
from rig.capture.frame import Frame, FramePair, FrameSet
from rig.capture.health import CaptureHealth, PairingHealth
from rig.capture.pairing import FramePairer
from rig.capture.protocol import Camera, FaultInjectable, TimeBase
from rig.capture.rates import RateAssessment, RateLimits, RateWindow
from rig.capture.supervisor import CameraSupervisor
from rig.counters import Tally, complete
from rig.errors import ConfigError, FaultNotSupported

__all__ = ["CAMERA_NAMES", "RigCapture", "StereoCapture", "default_skew_gate_ns"]

log = logging.getLogger("rig.capture")
CAMERA_NAMES = ("left", "right")
_WAIT_SLICE_S = 0.1
# How often the monitor thread samples the rates when nobody asks for the health.
_MONITOR_S = 0.5


def default_skew_gate_ns(fps_values: list[float | None]) -> int:
    """Half the frame period of the faster camera (30 fps → 16.7 ms)."""
    rates = [f for f in fps_values if f and f > 0]
    fps = max(rates) if rates else 30.0
    return round(0.5e9 / fps)


class RigCapture:
    """Supervised cameras (two, or a rig's N) and their synchronised sets. Thread-safe;
    ``stop()`` is idempotent."""

    def __init__(
        self,
        config: CaptureConfig,
        *,
        cameras: Mapping[str, Camera] | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self.config = config
        self._clock = clock
        self.names = config.names
        if cameras is None:
            timebase = TimeBase(clock)
            cameras = {n: open_camera(config.camera(n), n, timebase=timebase) for n in self.names}
        if set(cameras) != set(self.names):
            raise ConfigError(f"the capture needs cameras {self.names}, got {sorted(cameras)}")
        self._cameras = {n: cameras[n] for n in self.names}
        p = config.pairing
        gate = (
            round(p.skew_gate_ms * 1e6)
            if p.skew_gate_ms is not None
            else default_skew_gate_ns([c.nominal_fps for c in self._cameras.values()])
        )
        self._pairer = FramePairer(gate, p.buffer_size, p.skew_window, self.names)
        self._cond = threading.Condition()
        self._pairs: deque[FrameSet] = deque()
        self._counters = Tally("pairing")  # under self._cond; pairs_formed is the pairer's
        self._waiting = 0  # consumers waiting in next_pair (read unlocked by the decode choice)
        self._ended: set[str] = set()
        self._started = self._stopped = False
        sup = config.supervisor
        limits = RateLimits(sup.rate_window_s, sup.max_broken_fraction, sup.max_dropped_fraction)
        self._rates = {n: RateWindow(limits) for n in self.names}
        self._problems: dict[str, str | None] = dict.fromkeys(self.names)  # kind, under _problem_lock
        self._problem_lock = threading.Lock()
        self._monitor_stop = threading.Event()
        self._monitor: threading.Thread | None = None
        self._supervisors = {
            n: CameraSupervisor(
                cam,
                config.supervisor,
                self._on_frame,
                on_change=self._on_state_change,
                consumer_waiting=self._consumer_waiting,
                clock=clock,
            )
            for n, cam in self._cameras.items()
        }

    # ----- lifecycle ---------------------------------------------------------------------------
    def start(self) -> RigCapture:
        with self._cond:
            if self._started:
                return self
            self._started = True
        self._warn_bandwidth()
        for sup in self._supervisors.values():
            sup.start()
        self._monitor = threading.Thread(target=self._watch_rates, name="rig-capture-rates", daemon=True)
        self._monitor.start()
        return self

    def stop(self) -> None:
        with self._cond:
            if self._stopped:
                return
            self._stopped = True
            self._cond.notify_all()
        self._monitor_stop.set()
        if self._monitor is not None and self._monitor is not threading.current_thread():
            self._monitor.join(5.0)
        for sup in self._supervisors.values():
            sup.stop()

    def __enter__(self) -> RigCapture:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def skew_gate_ns(self) -> int:
        return self._pairer.gate_ns

    @property
    def exhausted(self) -> bool:
        """A camera ended (replay without loop), no further pair can form and none is waiting."""
        with self._cond:
            return self._pairer.exhausted and not self._pairs

    # ----- access for the service and fault injection -----------------------------------------
    def camera(self, name: str) -> Camera:
        self._check_name(name)
        return self._cameras[name]

    def supervisor(self, name: str) -> CameraSupervisor:
        self._check_name(name)
        return self._supervisors[name]

    def report_undecodable(self, frame: Frame, err: Exception) -> None:
        """The consumer could not decode ``frame`` (one of the pairs it took): counted against
        the frame's camera (:meth:`CameraSupervisor.report_undecodable`)."""
        self.supervisor(frame.camera).report_undecodable(str(err))

    def inject(self, name: str, fault: Fault) -> None:
        """Inject a fault into a camera that supports it (file cameras); FaultNotSupported otherwise."""
        cam = self.camera(name)
        if not isinstance(cam, FaultInjectable):
            raise FaultNotSupported(f"camera {name} ({cam.kind}) does not support fault injection")
        cam.inject(fault)

    def _check_name(self, name: str) -> None:
        if name not in self.names:
            raise ConfigError(f"unknown camera {name!r} (expected {' or '.join(map(repr, self.names))})")

    # ----- pairs -------------------------------------------------------------------------------
    def next_pair(self, timeout_s: float, *, newest: bool = True) -> FramePair | None:
        """:meth:`next_set` of a two-camera capture."""
        if len(self.names) != 2:
            raise ConfigError(f"a capture of {len(self.names)} cameras delivers sets, not pairs (next_set)")
        found = self.next_set(timeout_s, newest=newest)
        assert found is None or isinstance(found, FramePair)  # two cameras pair (rig.capture.pairing)
        return found

    def next_set(self, timeout_s: float, *, newest: bool = True) -> FrameSet | None:
        """The newest set not yet taken (or the oldest with ``newest=False``); waits up to
        ``timeout_s``; None on timeout, once finished, or when stopped."""
        deadline = time.monotonic() + max(0.0, timeout_s)
        with self._cond:
            while not self._pairs:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._stopped or self._pairer.exhausted:
                    return None
                self._waiting += 1
                try:
                    self._cond.wait(remaining)
                finally:
                    self._waiting -= 1
            if newest:
                pair = self._pairs.pop()
                self._counters.add("pairs_skipped", len(self._pairs))
                self._pairs.clear()
            else:
                pair = self._pairs.popleft()
            self._counters.add("pairs_taken")
            self._cond.notify_all()  # room for a camera thread waiting under backpressure
            return pair

    def _consumer_waiting(self) -> bool:
        """Whether a consumer is waiting in :meth:`next_pair` (it takes the next pair formed)."""
        return self._waiting > 0

    def _on_frame(self, frame: Frame) -> None:
        # Runs in a camera's capture thread. One push completes at most one pair (before it,
        # one of the two buffers is empty), so under backpressure the room is made first and the
        # pair goes straight into the buffer: no pair is ever in flight outside the lock.
        p = self.config.pairing
        with self._cond:
            if p.backpressure:
                self._wait_for_room(frame.camera)
            for pair in self._pairer.push(frame):
                if len(self._pairs) >= p.pair_buffer:
                    self._pairs.popleft()
                    self._counters.add("pairs_evicted")
                self._pairs.append(pair)
            self._cond.notify_all()

    def _wait_for_room(self, camera: str) -> None:
        """Backpressure (lock held, released while waiting): room for one pair, and room in the
        camera's buffer unless its peer has ended (then nothing more can pair with the oldest)."""
        p = self.config.pairing
        peers = set(self.names) - {camera}
        while not self._stopped:
            pairs_full = len(self._pairs) >= p.pair_buffer
            buffer_full = self._pairer.buffered(camera) >= p.buffer_size and not peers & self._ended
            if not (pairs_full or buffer_full):
                return
            self._cond.wait(_WAIT_SLICE_S)

    def _on_state_change(self) -> None:
        # Called by supervisors outside their own locks.
        ended = {n for n, s in self._supervisors.items() if s.state[0] == "ended"}
        with self._cond:
            for n in ended - self._ended:
                self._pairer.end(n)
            self._ended |= ended
            self._cond.notify_all()

    # ----- health ------------------------------------------------------------------------------
    def health(self) -> CaptureHealth:
        cams = {n: s.health() for n, s in self._supervisors.items()}
        with self._cond:
            counts = self._pairer.counts()
            p50, p95 = self._pairer.skew_percentiles_ms()
            pairing = PairingHealth(
                skew_gate_ms=self._pairer.gate_ns / 1e6,
                skew_samples=self._pairer.skew_samples,
                counters=complete(
                    "pairing",
                    {
                        **self._counters.snapshot(),
                        "pairs_formed": counts.pairs_formed,
                        "pairs_pending": len(self._pairs),
                        "skew_ms": p50,
                        "skew_ms_p95": p95,
                    },
                ),
            )
            finished = self._pairer.exhausted and not self._pairs
            running = self._started and not self._stopped
        now = self._clock()
        for n, h in cams.items():
            pairing_drops = {"frames_unpaired": counts.unpaired[n], "frames_evicted": counts.evicted[n]}
            counters = complete("camera", {**h.counters, **pairing_drops})
            rates = self._rates[n].observe(now, counters)
            reason = self._note_rates(n, rates, connected=h.connected)
            counters.update(
                corrupt_per_s=rates.corrupt_per_s,
                undecodable_per_s=rates.undecodable_per_s,
                dropped_per_s=rates.dropped_per_s,
            )
            cams[n] = replace(h, counters=counters, degraded_reason=reason)
        return CaptureHealth(running=running, finished=finished, cameras=cams, pairing=pairing)

    def _note_rates(self, name: str, rates: RateAssessment, *, connected: bool) -> str | None:
        """The camera's rate problem while it delivers (an unavailable camera has its own
        reason); logs once when a problem starts or changes kind, and once when it is over."""
        kind = rates.kind if connected else None
        with self._problem_lock:
            before, self._problems[name] = self._problems[name], kind
        if kind is not None and kind != before:
            log.warning("camera %s degraded: %s", name, rates.problem)
        elif kind is None and before is not None and connected:
            lim = self._rates[name].limits
            log.info(
                "camera %s recovered: frame losses back within limits (broken ≤ %.0f %%, dropped ≤ %.0f %% "
                "over %g s)",
                name,
                100 * lim.max_broken_fraction,
                100 * lim.max_dropped_fraction,
                lim.window_s,
            )
        return rates.problem if connected else None

    def _watch_rates(self) -> None:
        """Samples the rates while nobody polls the health (see module doc)."""
        while not self._monitor_stop.wait(_MONITOR_S):
            try:
                self.health()
            except Exception as err:  # a diagnostic must never stop capture
                log.debug("rate monitor: %s", err)

    # ----- USB bandwidth -----------------------------------------------------------------------
    def _warn_bandwidth(self) -> None:
        requests = {
            n: c
            for n in self.names
            if isinstance(c := self.config.camera(n), V4L2CameraConfig) and n in self._cameras
        }
        if len(requests) < 2:
            return
        from rig.usb import shared_bus_warnings  # sysfs only; no libusb needed

        try:
            warnings = shared_bus_warnings(
                {n: (c.device, c.fourcc, c.width, c.height, c.fps) for n, c in requests.items()}
            )
        except Exception as err:  # a diagnostic must never stop capture
            log.debug("USB bandwidth check skipped: %s", err)
            return
        for w in warnings:
            log.warning("%s", w)


#: The capture of two cameras (``left``, ``right``): the service's and ``rig record``'s name.
StereoCapture = RigCapture
