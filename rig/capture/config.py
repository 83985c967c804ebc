"""Capture configuration: the ``cameras:`` section of ``rig record --config`` and of the service.

```yaml
cameras:
  left:  {kind: v4l2, device: /dev/rig/left, fourcc: MJPG, width: 1280, height: 960, fps: 30}
  right: {kind: v4l2, device: /dev/rig/right, fourcc: MJPG, width: 1280, height: 960, fps: 30}
  pairing: {skew_gate_ms: null, buffer_size: 8}
  supervisor: {watchdog_s: 0.5}
```

A file-backed camera replays one camera of a recording instead::

  left: {kind: file, recording: rec/, camera: left, pace: 30, loop: true, timestamps: live}

or of a ROS bag (MCAP, ``.db3``, bag directory), its two image topics paired by header stamp::

  left: {kind: file, recording: run.mcap, left_topic: /cam0/image_raw, right_topic: /cam1/image_raw}

A rig of N cameras names its cameras under ``rig:`` instead of ``left`` and ``right`` (the names of
its rig.yaml; synchronised sets of N frames, docs/cameras.md)::

  rig:
    cam1: {kind: v4l2, device: /dev/rig/cam1}
    cam2: {kind: v4l2, device: /dev/rig/cam2}
    cam3: {kind: file, recording: ring/, camera: cam3}
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, ValidationError, field_validator, model_validator

from rig.capture.faults import Fault
from rig.errors import ConfigError
from rig.frame_sets import camera_name_problem
from rig.settings_model import (
    SettingsModel,
    describe_field_errors,
    field_errors,
    path_in_config,
    read_config_file,
)

__all__ = [
    "CAMERA_KINDS",
    "CameraConfig",
    "CaptureConfig",
    "FileCameraConfig",
    "PairingConfig",
    "SupervisorConfig",
    "V4L2CameraConfig",
    "capture_config_from_mapping",
    "load_capture_config",
    "resolve_camera_paths",
]


class V4L2CameraConfig(SettingsModel):
    """A UVC camera through OpenCV's V4L2 backend. Control values are raw V4L2 units."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["v4l2"] = "v4l2"
    device: str | int = Field(
        description="/dev/v4l/by-path/... (stable per USB port), a udev symlink such as "
        "/dev/rig/left, /dev/videoN, or an index"
    )
    fourcc: Literal["MJPG", "YUYV"] = "MJPG"
    width: int = Field(1280, ge=16, le=8192)
    height: int = Field(960, ge=16, le=8192)
    fps: float = Field(30.0, gt=0.0, le=500.0)
    buffer_size: int = Field(2, ge=1, le=10, description="V4L2 buffers (CAP_PROP_BUFFERSIZE)")
    exposure: float | None = Field(
        None, description="manual exposure (V4L2 exposure_time_absolute, 100 µs units); None = auto"
    )
    gain: float | None = Field(None, description="manual gain (driver units); None = leave as is")
    white_balance: float | None = Field(
        None, description="manual white balance temperature (K); None = auto white balance"
    )
    read_timeout_ms: int = Field(
        1000, ge=10, description="longest a grab may block (V4L2: OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT, whole s)"
    )
    timestamp_tolerance_ms: float = Field(
        1000.0, gt=0.0, description="buffer timestamps further than this from CLOCK_MONOTONIC → host clock"
    )
    fps_tolerance: float = Field(0.5, ge=0.0, description="accepted difference of negotiated fps")


class FileCameraConfig(SettingsModel):
    """One camera of a recording directory (docs/design.md) replayed through the camera protocol."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["file"] = "file"
    recording: Path
    camera: str | None = Field(None, description="camera of the recording; default: the slot name")
    pace: Literal["recorded", "fast"] | float = Field(
        "recorded", description="'recorded' (sleep by recorded deltas), 'fast', or a fixed fps"
    )
    loop: bool = False
    timestamps: Literal["recorded", "live"] = Field(
        "live", description="'recorded' = verbatim ts and seq; 'live' = rebased onto time.monotonic_ns()"
    )
    faults: tuple[Fault, ...] = ()
    left_topic: str | None = Field(None, description="a bag's image topic of the left camera")
    right_topic: str | None = Field(None, description="a bag's image topic of the right camera")
    max_skew_ms: float | None = Field(
        None, gt=0.0, description="a bag's pairing gate on header stamps; default half a frame period"
    )
    topics: dict[str, str] | None = Field(
        None, description="a bag's image topic of each camera of a rig (camera name: topic)"
    )

    @field_validator("pace")
    @classmethod
    def _positive_pace(cls, v: Any) -> Any:
        if isinstance(v, float) and not (0.0 < v <= 1000.0):
            raise ValueError("a numeric pace is frames per second in (0, 1000]")
        return v

    @model_validator(mode="after")
    def _both_topics(self) -> FileCameraConfig:
        if (self.left_topic is None) != (self.right_topic is None):
            raise ValueError("a bag needs both left_topic and right_topic (its two image topics)")
        if self.topics is not None and self.left_topic is not None:
            raise ValueError(
                "name a bag's topics per camera (topics) or as left_topic and right_topic, not both"
            )
        return self

    @model_validator(mode="after")
    def _live_needs_pacing(self) -> FileCameraConfig:
        if self.timestamps == "live" and self.pace == "fast":
            raise ValueError("timestamps 'live' need a paced replay (pace 'recorded' or an fps), not 'fast'")
        return self


CameraConfig = Annotated[V4L2CameraConfig | FileCameraConfig, Field(discriminator="kind")]


class PairingConfig(SettingsModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    skew_gate_ms: float | None = Field(
        None, gt=0.0, description="max |left-right| capture time difference; default half a frame period"
    )
    buffer_size: int = Field(8, ge=1, le=1000, description="frames held per camera waiting for a partner")
    pair_buffer: int = Field(4, ge=1, le=1000, description="complete pairs held for the consumer")
    skew_window: int = Field(300, ge=1, description="pairs in the skew p50/p95 window")
    backpressure: bool = Field(
        False,
        description="block camera threads instead of dropping when buffers are full (file replays only)",
    )


class SupervisorConfig(SettingsModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    watchdog_s: float = Field(
        0.5, gt=0.0, description="no frame for this long (or 3 frame periods, if longer) → unavailable"
    )
    reconnect_after_s: float = Field(2.0, gt=0.0, description="stalled this long → close and reopen")
    read_timeout_s: float = Field(0.25, gt=0.0, description="longest a single read may block")
    backoff_base_s: float = Field(0.1, gt=0.0)
    backoff_max_s: float = Field(5.0, gt=0.0)
    usb_reset_after: int = Field(5, ge=0, description="failed reopens before a USB reset; 0 = never")
    max_clock_offset_ms: float = Field(
        500.0, gt=0.0, description="host-clock timestamps older than this when their read began are rejected"
    )
    max_future_ms: float = Field(
        20.0, ge=0.0, description="host-clock timestamps later than their arrival by this are rejected"
    )
    decode: bool | Literal["auto"] = Field(
        "auto",
        description=(
            "decode frames' luma in the capture thread: true = every frame, false = none (only check "
            "markers; the depth worker decodes the pairs it takes), auto = while the depth worker "
            "waits for a pair (it takes the next one, so the decode is off its path)"
        ),
    )
    fps_window_s: float = Field(2.0, gt=0.0)
    rate_window_s: float = Field(
        10.0, ge=1.0, le=3600.0, description="window of the frame-loss rates that drive health (s)"
    )
    max_broken_fraction: float = Field(
        0.05,
        ge=0.0,
        le=1.0,
        description="corrupt + undecodable frames above this share of a camera's frames over the rate "
        "window → health degraded, naming the camera and the share",
    )
    max_dropped_fraction: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description="dropped frames (lost, unpaired, evicted) above this share of a camera's frames "
        "over the rate window → health degraded",
    )


class CaptureConfig(SettingsModel):
    """Two cameras (``left``, ``right``) or a rig of N named cameras (``rig``), plus pairing and
    supervision options."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    left: CameraConfig | None = None
    right: CameraConfig | None = None
    rig: dict[str, CameraConfig] | None = Field(
        None, description="a rig of N cameras by name (instead of left and right)"
    )
    pairing: PairingConfig = PairingConfig()
    supervisor: SupervisorConfig = SupervisorConfig()

    @model_validator(mode="after")
    def _cameras(self) -> CaptureConfig:
        if self.rig is not None:
            if self.left is not None or self.right is not None:
                raise ValueError("give either left and right, or rig (N cameras by name), not both")
            if len(self.rig) < 2:
                raise ValueError(f"rig: name two cameras or more, got {list(self.rig)}")
            for name in self.rig:
                problem = camera_name_problem(name)
                if problem is not None:
                    raise ValueError(f"rig: {problem}")
        elif self.left is None or self.right is None:
            missing = [n for n in ("left", "right") if getattr(self, n) is None]
            raise ValueError(f"{' and '.join(missing)} missing (or name N cameras under rig)")
        return self

    @property
    def names(self) -> list[str]:
        """The cameras, in order: ``left``, ``right`` or the rig's."""
        return list(self.rig) if self.rig is not None else ["left", "right"]

    def camera(self, name: str) -> V4L2CameraConfig | FileCameraConfig:
        if self.rig is not None:
            cam = self.rig.get(name)
        else:
            cam = self.left if name == "left" else self.right if name == "right" else None
        if cam is None:
            raise ConfigError(f"unknown camera {name!r} (expected {' or '.join(map(repr, self.names))})")
        return cam


#: The camera kinds: pydantic puts the kind of a camera into an error's location; a config file
#: does not spell it.
CAMERA_KINDS = ("file", "v4l2")


def resolve_camera_paths(cameras: Any, base: Path) -> Any:
    """A config file's raw ``cameras:`` section (the file in directory ``base``) with each file
    camera's ``recording`` relative to the file (:func:`rig.settings_model.path_in_config`);
    anything else as it is. The service's settings read the section through this too."""
    if not isinstance(cameras, Mapping):
        return cameras
    out = dict(cameras)
    for name in ("left", "right"):
        out[name] = _resolved(out.get(name), base)
        if out[name] is None:
            del out[name]
    rig = out.get("rig")
    if isinstance(rig, Mapping):
        out["rig"] = {name: _resolved(cam, base) for name, cam in rig.items()}
    return out


def _resolved(cam: Any, base: Path) -> Any:
    """A file camera's entry with its ``recording`` relative to ``base``; anything else as it is."""
    if isinstance(cam, Mapping) and cam.get("kind") == "file" and "recording" in cam:
        return {**cam, "recording": path_in_config(cam["recording"], base)}
    return cam


def capture_config_from_mapping(doc: Mapping[str, Any], source: str = "<config>") -> CaptureConfig:
    """Validate a ``cameras:`` mapping (of the config file ``source``, whose directory relative
    recording paths are relative to); ConfigError names the source and the field."""
    if not isinstance(doc, Mapping):
        raise ConfigError(f"{source}: field 'cameras' must be a mapping with 'left' and 'right' (or 'rig')")
    if source != "<config>":
        doc = resolve_camera_paths(doc, Path(source).parent)
    try:
        return CaptureConfig.model_validate(dict(doc))
    except ValidationError as err:
        errors = field_errors(err, prefix=("cameras",), hide=CAMERA_KINDS)
        raise ConfigError(f"{source}: {describe_field_errors(errors)}") from err


def load_capture_config(path: str | Path) -> CaptureConfig:
    """Read the ``cameras:`` section of a YAML config file (:func:`rig.settings_model.read_config_file`)."""
    p = Path(path)
    doc = read_config_file(p)
    if "cameras" not in doc:
        raise ConfigError(f"{p}: field 'cameras' missing (the capture section with 'left' and 'right')")
    return capture_config_from_mapping(doc["cameras"], str(p))
