"""Faults a file-backed camera can simulate, as config (a schedule) and at runtime.

Each fault is a pydantic model (so it can sit in a YAML camera config) with an optional trigger:
``at_frame`` (fires once the camera has delivered that many frames since it was created) or
``at_s`` (seconds after the camera was first opened). A fault given to ``FileCamera.inject`` at
runtime fires before the next frame. What each fault does, exactly (the counters depend on it):

- ``stall`` (duration_s): no frames for the duration. A paced camera keeps its schedule, so the
  frames scheduled during the stall are lost (they show as gaps in ``seq``); an unpaced ("fast")
  camera just pauses.
- ``disconnect`` (duration_s): ``read`` raises CameraUnavailable and ``open`` fails until the
  duration has passed; then the device "reappears". Frames scheduled meanwhile are lost.
- ``corrupt`` (count): the next ``count`` frames have their header overwritten with zeros (keeps
  the first two bytes); they no longer decode and fail the structural check.
- ``truncate`` (count): the next ``count`` frames are cut to half their length.
- ``timestamp_jump`` (offset_ms): every later timestamp is shifted by the offset until the camera
  is re-opened (re-opening re-validates a real camera's clock; the supervisor reconnects on a
  timestamp error).
- ``rate`` (factor, frames | duration_s): keeps one frame in ``round(1/factor)`` of the next
  ``frames`` recorded frames (or of those scheduled within ``duration_s``); the others are lost.
- ``drop`` (count): the next ``count`` frames are lost.

Durations and clock offsets are at most ``MAX_FAULT_S`` (a day). The JSON schema states the
validators' cross-field rules too (one trigger at most, ``offset_ms`` not 0, a rate fault with
exactly one of ``frames``/``duration_s``), so API clients see them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any, ClassVar, Literal

from pydantic import ConfigDict, Field, TypeAdapter, model_validator

from rig.settings_model import SettingsModel

__all__ = [
    "MAX_FAULT_S",
    "CorruptFault",
    "DisconnectFault",
    "DropFault",
    "Fault",
    "FaultPlan",
    "RateFault",
    "StallFault",
    "TimestampJumpFault",
    "TruncateFault",
    "parse_fault",
]


#: Longest stall/disconnect/rate window and largest clock jump: beyond a day nothing is tested,
#: and the nanosecond arithmetic stays finite.
MAX_FAULT_S = 86_400.0


def _fault_schema(schema: dict[str, Any], cls: type) -> None:
    """State the validators' cross-field rules in the JSON schema too (API clients and
    schemathesis read it): ``kind`` is the discriminator, so it is required there."""
    required = schema.setdefault("required", [])
    if "kind" not in required:
        required.append("kind")
    both = {"at_frame": {"type": "integer"}, "at_s": {"type": "number"}}
    rules: list[dict[str, Any]] = [{"not": {"properties": both, "required": list(both)}}]
    schema["allOf"] = rules + list(getattr(cls, "SCHEMA_RULES", []))


class _Trigger(SettingsModel):
    model_config = ConfigDict(extra="forbid", frozen=True, json_schema_extra=_fault_schema)

    at_frame: int | None = Field(None, ge=0, description="fire after this many delivered frames")
    at_s: float | None = Field(None, ge=0.0, description="fire this long after the first open")

    @model_validator(mode="after")
    def _one_trigger(self) -> _Trigger:
        if self.at_frame is not None and self.at_s is not None:
            raise ValueError("give at_frame or at_s, not both")
        return self


class StallFault(_Trigger):
    kind: Literal["stall"] = "stall"
    duration_s: float = Field(gt=0.0, le=MAX_FAULT_S)


class DisconnectFault(_Trigger):
    kind: Literal["disconnect"] = "disconnect"
    duration_s: float = Field(gt=0.0, le=MAX_FAULT_S)


class CorruptFault(_Trigger):
    kind: Literal["corrupt"] = "corrupt"
    count: int = Field(1, ge=1)


class TruncateFault(_Trigger):
    kind: Literal["truncate"] = "truncate"
    count: int = Field(1, ge=1)


class TimestampJumpFault(_Trigger):
    kind: Literal["timestamp_jump"] = "timestamp_jump"
    offset_ms: float = Field(
        ge=-MAX_FAULT_S * 1e3, le=MAX_FAULT_S * 1e3, json_schema_extra={"not": {"const": 0}}
    )

    @model_validator(mode="after")
    def _nonzero(self) -> TimestampJumpFault:
        if self.offset_ms == 0:
            raise ValueError("offset_ms must not be 0")
        return self


class RateFault(_Trigger):
    SCHEMA_RULES: ClassVar[list[dict[str, Any]]] = [
        {
            "oneOf": [
                {"properties": {"frames": {"type": "integer"}}, "required": ["frames"]},
                {"properties": {"duration_s": {"type": "number"}}, "required": ["duration_s"]},
            ]
        }
    ]

    kind: Literal["rate"] = "rate"
    factor: float = Field(0.5, gt=0.0, lt=1.0, description="fraction of frames kept")
    frames: int | None = Field(None, ge=1, description="recorded frames the reduction applies to")
    duration_s: float | None = Field(
        None, gt=0.0, le=MAX_FAULT_S, description="or: scheduled time it applies to"
    )

    @model_validator(mode="after")
    def _one_extent(self) -> RateFault:
        if (self.frames is None) == (self.duration_s is None):
            raise ValueError("give exactly one of frames or duration_s")
        return self

    @property
    def keep_every(self) -> int:
        return max(1, round(1.0 / self.factor))


class DropFault(_Trigger):
    kind: Literal["drop"] = "drop"
    count: int = Field(1, ge=1)


Fault = Annotated[
    StallFault | DisconnectFault | CorruptFault | TruncateFault | TimestampJumpFault | RateFault | DropFault,
    Field(discriminator="kind"),
]
_FAULT_ADAPTER: TypeAdapter[Fault] = TypeAdapter(Fault)


def parse_fault(doc: object) -> Fault:
    """A fault from a mapping like ``{"kind": "stall", "duration_s": 3}`` (pydantic validation)."""
    return _FAULT_ADAPTER.validate_python(doc)


@dataclass
class _RateWindow:
    keep_every: int
    frames_left: int | None  # recorded frames still affected (frames form)
    until_ns: int | None  # schedule time it ends (duration form)
    position: int = 0


class FaultPlan:
    """Pending and active faults of one camera. Not thread-safe: the camera calls it under its lock.

    The camera asks, frame by frame: which scheduled faults are due (:meth:`fire_due`), whether
    it is stalled/disconnected at a time, whether the next recorded frame is lost, and how to
    mangle the bytes and timestamp of a frame it delivers.
    """

    def __init__(self, schedule: list[Fault] | tuple[Fault, ...] = ()) -> None:
        self._pending: list[Fault] = list(schedule)
        self.stall_until_ns: int | None = None
        self.disconnect_until_ns: int | None = None
        self.corrupt_left = 0
        self.truncate_left = 0
        self.drop_left = 0
        self.jump_offset_ns = 0
        self._rate: _RateWindow | None = None
        self.fired: list[Fault] = []

    def inject(self, fault: Fault, now_ns: int) -> None:
        """Activate a fault now (runtime form; its trigger fields are ignored)."""
        self.fired.append(fault)
        if isinstance(fault, StallFault):
            end = now_ns + round(fault.duration_s * 1e9)
            self.stall_until_ns = max(self.stall_until_ns or 0, end)
        elif isinstance(fault, DisconnectFault):
            end = now_ns + round(fault.duration_s * 1e9)
            self.disconnect_until_ns = max(self.disconnect_until_ns or 0, end)
        elif isinstance(fault, CorruptFault):
            self.corrupt_left += fault.count
        elif isinstance(fault, TruncateFault):
            self.truncate_left += fault.count
        elif isinstance(fault, TimestampJumpFault):
            self.jump_offset_ns += round(fault.offset_ms * 1e6)
        elif isinstance(fault, RateFault):
            until = None if fault.duration_s is None else now_ns + round(fault.duration_s * 1e9)
            self._rate = _RateWindow(fault.keep_every, fault.frames, until)
        elif isinstance(fault, DropFault):
            self.drop_left += fault.count

    def fire_due(self, delivered: int, elapsed_s: float | None, now_ns: int) -> list[Fault]:
        """Activate scheduled faults whose trigger is reached; returns them.

        ``now_ns`` is the moment they take effect (for a paced camera: the schedule time of the
        next frame, so a stall scheduled ``at_frame`` loses the same frames on every run).
        """
        due = [
            f
            for f in self._pending
            if (f.at_frame is not None and delivered >= f.at_frame)
            or (f.at_s is not None and elapsed_s is not None and elapsed_s >= f.at_s)
            or (f.at_frame is None and f.at_s is None)
        ]
        for f in due:
            self._pending.remove(f)
            self.inject(f, now_ns)
        return due

    def stalled(self, now_ns: int) -> bool:
        return self.stall_until_ns is not None and now_ns < self.stall_until_ns

    def disconnected(self, now_ns: int) -> bool:
        return self.disconnect_until_ns is not None and now_ns < self.disconnect_until_ns

    def outage_end_ns(self) -> int | None:
        """End of the latest stall/disconnect window, for skipping frames scheduled inside it."""
        ends = [t for t in (self.stall_until_ns, self.disconnect_until_ns) if t is not None]
        return max(ends) if ends else None

    def lose_next(self, scheduled_ns: int | None) -> bool:
        """Whether the next recorded frame (scheduled at ``scheduled_ns``) is lost to a fault."""
        if self.drop_left > 0:
            self.drop_left -= 1
            return True
        rate = self._rate
        if rate is None:
            return False
        if rate.until_ns is not None and (scheduled_ns is None or scheduled_ns >= rate.until_ns):
            self._rate = None
            return False
        keep = rate.position % rate.keep_every == 0
        rate.position += 1
        if rate.frames_left is not None:
            rate.frames_left -= 1
            if rate.frames_left <= 0:
                self._rate = None
        return not keep

    def mangle(self, data: bytes) -> tuple[bytes, str | None]:
        """Apply pending corrupt/truncate faults to one delivered frame's bytes."""
        if self.corrupt_left > 0:
            self.corrupt_left -= 1
            n = min(len(data), 66)
            return data[:2] + b"\x00" * max(0, n - 2) + data[n:], "corrupt"
        if self.truncate_left > 0:
            self.truncate_left -= 1
            return data[: len(data) // 2], "truncate"
        return data, None

    def reset_clock(self) -> None:
        """Re-opening the camera re-validates its clock: a timestamp jump ends."""
        self.jump_offset_ns = 0
