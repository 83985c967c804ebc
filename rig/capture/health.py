"""Typed health snapshots of the capture: what ``/health`` and the Prometheus metrics read.

Each snapshot holds its descriptive attributes (state, device, last error, ...) and its
``counters``: the figures of its group in :mod:`rig.counters`, which declares and explains every
one of them (see ``docs/counters.md``). All camera counters are exact for file cameras, which
makes them testable.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from rig.counters import Counts, flatten

__all__ = ["CameraHealth", "CameraState", "CaptureHealth", "PairingHealth"]

CameraState = Literal["starting", "available", "unavailable", "ended", "stopped"]


@dataclass(frozen=True)
class CameraHealth:
    name: str
    kind: str
    device: str
    state: CameraState
    reason: str | None
    nominal_fps: float | None
    last_seq: int | None
    last_ts_ns: int | None
    timestamp_source: str | None
    timestamp_note: str | None
    last_error: str | None
    last_error_age_ms: float | None
    format: str
    width: int
    height: int
    #: The frame-loss rates over the window are above a limit (rig.capture.rates): what is wrong.
    degraded_reason: str | None
    counters: Counts  # rig.counters, group "camera"

    @property
    def connected(self) -> bool:
        return self.state == "available"


@dataclass(frozen=True)
class PairingHealth:
    skew_gate_ms: float
    skew_samples: int
    counters: Counts  # rig.counters, group "pairing"


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
        """Plain JSON-able dict, counters side by side with the attributes (as in ``/health``)."""
        return {
            "running": self.running,
            "finished": self.finished,
            "cameras": {name: flatten(c) for name, c in self.cameras.items()},
            "pairing": flatten(self.pairing),
        }
