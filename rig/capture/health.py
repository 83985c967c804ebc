"""Typed health snapshots of the capture: what ``/health`` and the Prometheus metrics read.

Counter definitions (per camera; all exact for file cameras, which makes them testable):

- ``frames_received``: frames that passed validation and timestamp checks and went to pairing.
- ``frames_corrupt``: frames whose bytes failed the structural check or did not decode; they
  never reach pairing.
- ``frames_undecodable``: received frames whose luma did not decode when the depth worker took
  them. Which thread decodes a frame follows ``SupervisorConfig.decode``: the capture thread's
  failures count in ``frames_corrupt`` (with ``decode: true`` all of them: this stays 0), the
  worker's here.
- ``timestamp_errors``: frames rejected because a host-clock timestamp was more than
  ``max_clock_offset_ms`` from the arrival time or did not increase; each triggers a reconnect.
- ``frames_lost``: gaps in the camera's ``seq`` (frames the camera or driver never delivered).
  A ``seq`` that goes down starts a new stream and counts nothing.
- ``frames_unpaired``: received frames dropped by pairing because no partner was within the gate.
- ``frames_evicted``: received frames pushed out of the full per-camera pairing buffer.
- ``frames_dropped`` = ``frames_lost + frames_unpaired + frames_evicted``.

Pairing: ``pairs_formed`` = ``pairs_taken + pairs_skipped + pairs_evicted + pairs_pending``;
``pairs_skipped`` are pairs superseded by a newer one when the consumer asks for the newest,
``pairs_evicted`` were pushed out of the full pair buffer.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Literal

__all__ = ["CameraHealth", "CameraState", "CaptureHealth", "PairingHealth"]

CameraState = Literal["starting", "available", "unavailable", "ended", "stopped"]


@dataclass(frozen=True)
class CameraHealth:
    name: str
    kind: str
    device: str
    state: CameraState
    reason: str | None
    connected: bool
    fps: float
    nominal_fps: float | None
    last_frame_age_ms: float | None
    last_seq: int | None
    last_ts_ns: int | None
    frames_received: int
    frames_corrupt: int
    frames_undecodable: int
    frames_lost: int
    frames_unpaired: int
    frames_evicted: int
    frames_dropped: int
    timestamp_errors: int
    reconnects: int
    reconnect_attempts: int
    usb_resets: int
    timestamp_source: str | None
    timestamp_note: str | None
    last_error: str | None
    last_error_age_ms: float | None
    format: str
    width: int
    height: int


@dataclass(frozen=True)
class PairingHealth:
    skew_gate_ms: float
    pairs_formed: int
    pairs_taken: int
    pairs_skipped: int
    pairs_evicted: int
    pairs_pending: int
    skew_ms_p50: float | None
    skew_ms_p95: float | None
    skew_samples: int


@dataclass(frozen=True)
class CaptureHealth:
    running: bool
    finished: bool
    cameras: dict[str, CameraHealth]
    pairing: PairingHealth

    @property
    def all_connected(self) -> bool:
        return all(c.connected for c in self.cameras.values())

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (the service serialises this)."""
        return asdict(self)
