"""Service settings: a YAML config file plus ``RIG_*`` environment variables (pydantic-settings).

Precedence, highest first: explicit overrides (the CLI's ``--host``/``--port``…), environment
(``RIG_SERVER__PORT=9000``, nested with ``__``; ``RIG_API_TOKEN`` for ``server.api_token``), the
config file (``--config FILE`` or ``RIG_CONFIG``), defaults. Relative paths in the config file
resolve relative to the file; relative paths from the environment to the working directory.

```yaml
server: {host: 127.0.0.1, port: 8000, depth_scale_m: 0.001, recordings_dir: recordings,
         foxglove: {enabled: false, host: 127.0.0.1, port: 8765}}
cameras:                         # rig.capture.CaptureConfig; omitted = no cameras (demo)
  left:  {kind: v4l2, device: /dev/rig/left}
  right: {kind: v4l2, device: /dev/rig/right}
calibration: {path: rig.yaml}    # rig.yaml or Kalibr camchain.yaml
rectified: {projection: latlon, px_per_deg: 5.585}  # or {projection: pinhole, width: 640, height: 480}
                                 # (read as "vpc:" too, the section's first name)
stereo: {disparity_range: 96}    # rig.stereo.StereoParams
ros: {namespace: /rig}           # rig.ros.RosNames: topic names and frame ids (Foxglove, MCAP)
rectification: {check_interval_s: 10, auto_refine: false}   # rig.rectification.RectificationConfig
depth_watch: {recent_s: 10, reference_s: 60}   # collapsing valid depth is reported (rig.depth_watch)
pinhole_depth: {width: 640, height: 480, hfov_deg: 90}  # /depth/pinhole: z on a pinhole (rig.pinhole_depth)
panorama: {px_per_deg: 4}        # a rig of more than two cameras: its fused panorama (rig.panorama)
cache_dir: null                  # LUT cache (default: $RIG_CACHE_DIR or the user cache dir)
```

Nothing here touches a camera or a file other than the config file: building the runtime is
:mod:`service.runtime`'s job.
"""

from __future__ import annotations

import ipaddress
import os
from collections.abc import Collection, Iterator, Mapping, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Any

import platformdirs
from pydantic import (
    ConfigDict,
    Field,
    SecretStr,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic.fields import FieldInfo
from pydantic_core import ErrorDetails
from pydantic_settings import BaseSettings, PydanticBaseSettingsSource, SettingsConfigDict

from rig.capture.config import CAMERA_KINDS, CaptureConfig, resolve_camera_paths
from rig.colormap import DEFAULT_RANGE_M
from rig.errors import ConfigError
from rig.panorama import PanoramaConfig
from rig.pinhole_depth import PinholeDepthConfig
from rig.rectification.monitor import RectificationConfig
from rig.rectified import RectifiedPairConfig
from rig.ros.names import RosNames
from rig.settings_model import (
    SettingsModel,
    describe_field_errors,
    field_errors,
    path_in_config,
    read_config_file,
)
from rig.stereo import StereoParams
from service.errors import SettingsError

__all__ = [
    "CONFIG_ENV",
    "TOKEN_ENV",
    "CalibrationSettings",
    "DepthWatchSettings",
    "FoxgloveSettings",
    "ServerSettings",
    "Settings",
    "is_loopback",
    "load_settings",
    "settings_summary",
]

CONFIG_ENV = "RIG_CONFIG"
TOKEN_ENV = "RIG_API_TOKEN"
ENV_PREFIX = "RIG_"
MIN_TOKEN_CHARS = 16
DEPTH_SCALES = (0.001, 0.0001)


def default_recordings_dir() -> Path:
    return Path(platformdirs.user_data_dir("odfc-rig")) / "recordings"


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback IP literals (127.0.0.0/8, ::1)."""
    if host.strip().lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


class FoxgloveSettings(SettingsModel):
    """The Foxglove WebSocket server (foxglove-sdk) of ``rig serve``: read-only, off by default."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(False, description="run the Foxglove WebSocket server")
    host: str = Field(
        "127.0.0.1",
        min_length=1,
        description="bind address; non-loopback needs api_token, which viewers present",
    )
    port: int = Field(8765, ge=0, le=65535, description="TCP port (0 = any free port)")
    max_fps: float = Field(10.0, gt=0.0, le=60.0, description="most depth frames per second sent to viewers")
    cloud_stride: int = Field(2, ge=1, le=64, description="every n-th pixel of each axis in the point cloud")
    message_backlog: int = Field(
        16,
        ge=4,
        le=4096,
        description="messages queued per viewer (every topic of about one frame); a viewer that falls "
        "behind loses the oldest",
    )
    max_viewers: int = Field(
        8,
        ge=1,
        le=1000,
        description="open connections to the Foxglove port; beyond, the one waiting longest for its "
        "request is closed, or the new one answered 503 if all are viewers",
    )
    handshake_timeout_s: float = Field(
        10.0, gt=0.0, le=600.0, description="a connection's upgrade request must arrive within this: 408"
    )
    idle_timeout_s: float = Field(
        60.0, gt=0.0, le=86400.0, description="a viewer that sends and receives nothing for this is closed"
    )
    stall_s: float = Field(
        10.0,
        gt=0.0,
        le=600.0,
        description="a viewer that has not taken what was sent to it within this is closed",
    )


class ServerSettings(SettingsModel):
    """HTTP server, security and response options."""

    model_config = ConfigDict(extra="forbid")

    host: str = Field("127.0.0.1", min_length=1, description="bind address; non-loopback needs a token")
    port: int = Field(8000, ge=0, le=65535, description="TCP port (0 = any free port)")
    api_token: SecretStr | None = Field(
        None, description=f"bearer token for state-changing endpoints (env {TOKEN_ENV})"
    )
    cors_origins: list[str] = Field(default_factory=list, description="allowed CORS origins; [] = CORS off")
    max_body_bytes: int = Field(64 * 1024, ge=256, le=64 * 1024 * 1024, description="request body limit")
    depth_scale_m: float = Field(
        0.001, description="metres per unit of the 16-bit depth PNG: 0.001 or 0.0001"
    )
    recordings_dir: Path = Field(default_factory=default_recordings_dir)
    jpeg_quality: int = Field(85, ge=10, le=100)
    png_compression: int = Field(
        1,
        ge=0,
        le=9,
        description="deflate level of the 16-bit PNG bodies (/depth, /disparity): 1 = ~230 KiB at "
        "640×480 for ~1.4 ms of CPU per frame (ISA-L); 0 = stored, ~600 KiB for about the same CPU "
        "(spares clients the inflate); 2-9 = libpng/zlib: 2 = ~230 KiB for ~11 ms, 6 = ~220 KiB for ~34 ms",
    )
    stream_fps: float = Field(10.0, gt=0.0, le=60.0, description="max parts per second of /stream.mjpg")
    max_streams: int = Field(
        16, ge=1, le=1000, description="concurrent /stream.mjpg clients; more are answered 503"
    )
    stream_stall_s: float = Field(
        10.0,
        gt=0.0,
        le=600.0,
        description="a /stream.mjpg client that has not taken a part within this is dropped",
    )
    max_connections: int = Field(
        128,
        ge=8,
        le=100_000,
        description="open HTTP connections; beyond, the one idle longest is closed, or the new one "
        "answered 503 if all are busy",
    )
    max_header_bytes: int = Field(
        16 * 1024, ge=1024, le=1024 * 1024, description="request line and headers; larger: 431"
    )
    max_headers: int = Field(100, ge=8, le=10_000, description="header lines of a request; more: 431")
    request_timeout_s: float = Field(
        10.0,
        gt=0.0,
        le=600.0,
        description="a request's head and body must arrive within this of its first byte (of the "
        "connection, for the first request): 408 otherwise",
    )
    keep_alive_s: int = Field(5, ge=1, le=600, description="idle keep-alive connections close after this")
    color_range_m: tuple[float, float] = Field(
        DEFAULT_RANGE_M, description="depth range spanned by the colour map (near, far), log scale"
    )
    recording_queue: int = Field(64, ge=1, le=10_000, description="pairs waiting for the recording writer")
    stale_after_s: float = Field(2.0, gt=0.0, description="no depth frame for this long → degraded")
    health_max_age_s: float = Field(
        0.1, ge=0.0, le=1.0, description="/health document shared by requests within this age (0 = none)"
    )
    fault_injection: bool = Field(False, description="expose POST /cameras/{name}/faults (file cameras)")
    foxglove: FoxgloveSettings = Field(default_factory=FoxgloveSettings)
    depth_nice: int | None = Field(
        -5,
        ge=-20,
        le=19,
        description="nice value of the capture, depth and recording threads, HTTP staying at the "
        "process's: clients cannot starve the frame rate (below 0 needs root, CAP_SYS_NICE or "
        "LimitNICE; null = leave all threads alone)",
    )

    @field_validator("api_token", mode="before")
    @classmethod
    def _empty_token_is_none(cls, v: Any) -> Any:
        if v is None or (isinstance(v, str) and not v.strip()):
            return None
        return v

    @field_validator("api_token")
    @classmethod
    def _token_length(cls, v: SecretStr | None) -> SecretStr | None:
        if v is not None and len(v.get_secret_value()) < MIN_TOKEN_CHARS:
            raise ValueError(f"the API token must have at least {MIN_TOKEN_CHARS} characters")
        return v

    @field_validator("depth_scale_m", mode="before")
    @classmethod
    def _known_scale(cls, v: Any) -> Any:
        try:
            value = float(v)
        except (TypeError, ValueError):
            raise ValueError(f"must be one of {DEPTH_SCALES} (m per unit), got {v!r}") from None
        for scale in DEPTH_SCALES:
            if abs(value - scale) < 1e-12:
                return scale
        raise ValueError(f"must be one of {DEPTH_SCALES} (1 mm or 0.1 mm per unit), got {v!r}")

    @field_validator("color_range_m")
    @classmethod
    def _ordered_range(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not (0.0 < v[0] < v[1]):
            raise ValueError(f"must be (near, far) with 0 < near < far, got {v}")
        return v

    @model_validator(mode="after")
    def _streams_within_connections(self) -> ServerSettings:
        if self.max_streams >= self.max_connections:
            raise ValueError(
                f"max_streams ({self.max_streams}) must be below max_connections ({self.max_connections}): "
                "streams hold connections"
            )
        return self

    @model_validator(mode="after")
    def _loopback_or_token(self) -> ServerSettings:
        for what, host in (("", self.host), ("the Foxglove server on ", self.foxglove.host)):
            if not is_loopback(host) and self.api_token is None:
                raise ValueError(
                    f"refusing to bind {what}non-loopback address {host!r} without an API token: "
                    f"set {TOKEN_ENV}"
                )
        return self

    @property
    def token(self) -> str | None:
        return None if self.api_token is None else self.api_token.get_secret_value()


class DepthWatchSettings(SettingsModel):
    """The depth watch (rig.depth_watch): valid depth that collapses is reported as degraded."""

    model_config = ConfigDict(extra="forbid")

    recent_s: float = Field(10.0, gt=0.0, le=3600.0, description="the recent window whose median is judged")
    reference_s: float = Field(60.0, gt=0.0, le=86400.0, description="the window before it, the reference")
    collapse_ratio: float = Field(
        0.35, gt=0.0, lt=1.0, description="recent median below this share of the reference: collapsed"
    )


class CalibrationSettings(SettingsModel):
    model_config = ConfigDict(extra="forbid")

    path: Path | None = Field(
        None,
        description="rig.yaml or Kalibr camchain.yaml; default: the replayed recording's calibration.yaml",
    )


# The config file's contents for the Settings being built (set by load_settings only).
_FILE_DATA: ContextVar[dict[str, Any] | None] = ContextVar("rig_settings_file_data", default=None)


class _FileSource(PydanticBaseSettingsSource):
    def get_field_value(self, field: FieldInfo, field_name: str) -> tuple[Any, str, bool]:
        return None, field_name, False

    def __call__(self) -> dict[str, Any]:
        return dict(_FILE_DATA.get() or {})


class _TokenEnvSource(PydanticBaseSettingsSource):
    """``RIG_API_TOKEN`` → ``server.api_token`` (the documented short name)."""

    def get_field_value(self, field: FieldInfo, field_name: str) -> tuple[Any, str, bool]:
        return None, field_name, False

    def __call__(self) -> dict[str, Any]:
        token = os.environ.get(TOKEN_ENV)
        return {} if token is None else {"server": {"api_token": token}}


class Settings(BaseSettings):
    """Everything ``rig serve`` needs; see the module docstring for sources and precedence."""

    model_config = SettingsConfigDict(env_prefix=ENV_PREFIX, env_nested_delimiter="__", extra="forbid")

    server: ServerSettings = Field(default_factory=ServerSettings)
    cameras: CaptureConfig | None = Field(None, description="the capture section; None = none configured")
    calibration: CalibrationSettings = Field(default_factory=CalibrationSettings)
    rectified: RectifiedPairConfig = Field(
        default_factory=RectifiedPairConfig, description="the rectified pair: projection, size, field"
    )
    vpc: RectifiedPairConfig | None = Field(
        None, exclude=True, description="the first name of 'rectified' (virtual pinhole cameras), still read"
    )
    stereo: StereoParams = Field(default_factory=StereoParams)
    ros: RosNames = Field(default_factory=RosNames)
    cache_dir: Path | None = Field(None, description="LUT cache directory (env RIG_CACHE_DIR)")
    rectification: RectificationConfig = Field(
        default_factory=RectificationConfig, description="live rectification measure and online refinement"
    )
    pinhole_depth: PinholeDepthConfig = Field(
        default_factory=PinholeDepthConfig,
        description="the pinhole depth image cut from the range (/depth/pinhole, ROS tools read it)",
    )
    depth_watch: DepthWatchSettings = Field(
        default_factory=DepthWatchSettings, description="valid depth that collapses is reported"
    )
    panorama: PanoramaConfig = Field(
        default_factory=PanoramaConfig,
        description="the panorama fused from every pair of a rig of more than two cameras",
    )

    @model_validator(mode="after")
    def _vpc_is_rectified(self) -> Settings:
        if self.vpc is not None:
            if "rectified" in self.model_fields_set:
                raise ValueError(
                    "give the rectified pair as 'rectified' or as 'vpc' (its first name), not both"
                )
            # Frozen sections, mutable settings: the section moves to its name of today.
            self.rectified, self.vpc = self.vpc, None
        return self

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        return (
            init_settings,
            _TokenEnvSource(settings_cls),
            env_settings,
            _FileSource(settings_cls),
            file_secret_settings,
        )


# ----- loading ---------------------------------------------------------------------------------
_PATH_FIELDS = (
    ("server", "recordings_dir"),
    ("calibration", "path"),
    ("cache_dir",),
    ("rectification", "persist_path"),
)


def _resolve_relative(doc: dict[str, Any], base: Path) -> dict[str, Any]:
    """Paths in a config file are relative to the file (a copy; the input is not changed)."""
    out = {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in doc.items()}
    for path in _PATH_FIELDS:
        holder: Any = out
        for key in path[:-1]:
            holder = holder.get(key) if isinstance(holder, dict) else None
        if isinstance(holder, dict) and path[-1] in holder:
            holder[path[-1]] = path_in_config(holder[path[-1]], base)
    if "cameras" in out:
        out["cameras"] = resolve_camera_paths(out["cameras"], base)
    return out


def _read_config(path: Path) -> dict[str, Any]:
    """The config file (:func:`rig.settings_model.read_config_file`, the one reader) with its
    relative paths resolved."""
    try:
        doc = read_config_file(path)
    except ConfigError as err:
        raise SettingsError(str(err)) from err
    return _resolve_relative(doc, path.parent)


def _source_of(loc: tuple[int | str, ...], config: Path | None) -> str:
    if tuple(loc[:2]) == ("server", "api_token") and TOKEN_ENV in os.environ:
        return f"environment {TOKEN_ENV}"
    parts = [str(p) for p in loc if p not in CAMERA_KINDS]
    for n in range(len(parts), 0, -1):
        name = ENV_PREFIX + "__".join(parts[:n]).upper()
        if name in os.environ:
            return f"environment {name}"
    return str(config) if config is not None else "settings"


@contextmanager
def _file_data(doc: dict[str, Any]) -> Iterator[None]:
    token = _FILE_DATA.set(doc)
    try:
        yield
    finally:
        _FILE_DATA.reset(token)


def load_settings(
    config: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    *,
    replace: Collection[str] = (),
) -> Settings:
    """Settings from ``config`` (default: ``$RIG_CONFIG``; none = defaults), the environment and
    ``overrides`` (nested mapping, highest precedence). The top-level sections in ``replace``
    (``cameras`` for ``rig serve --demo``) are taken from ``overrides`` alone instead of merged
    into the file's. Every value of the file and the environment is validated even where an
    override takes its place (a wrong value is wrong, whether used today or not); rules between
    fields apply to the settings in effect. SettingsError lists every mistake, each with its
    file (or environment variable) and field."""
    if config is None and os.environ.get(CONFIG_ENV):
        config = os.environ[CONFIG_ENV]
    path = Path(config).expanduser() if config is not None else None
    doc = _read_config(path) if path is not None else {}
    overrides = dict(overrides or {})
    if overrides:
        with _file_data(doc):
            _check_own_values(path, overrides)
    try:
        with _file_data({k: v for k, v in doc.items() if k not in replace}):
            return Settings(**overrides)
    except ValidationError as err:
        raise SettingsError(_describe(err.errors(), path)) from err


def _check_own_values(config: Path | None, overrides: Mapping[str, Any]) -> None:
    """The file's and the environment's values on their own. Errors of a model that contains an
    overridden value (a rule between its fields, such as a non-loopback host without a token)
    are left to the settings in effect."""
    try:
        Settings()
    except ValidationError as err:
        overridden = _leaf_paths(overrides)
        own = [
            e
            for e in err.errors()
            if not any(_strictly_within(_plain(e["loc"]), leaf) for leaf in overridden)
        ]
        if own:
            raise SettingsError(_describe(own, config)) from err


def _leaf_paths(doc: Mapping[str, Any], prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out: list[tuple[str, ...]] = []
    for key, value in doc.items():
        path = (*prefix, str(key))
        out += _leaf_paths(value, path) if isinstance(value, Mapping) and value else [path]
    return out


def _plain(loc: tuple[int | str, ...]) -> tuple[str, ...]:
    return tuple(str(p) for p in loc if p not in CAMERA_KINDS)


def _strictly_within(loc: tuple[str, ...], leaf: tuple[str, ...]) -> bool:
    return len(loc) < len(leaf) and leaf[: len(loc)] == loc


def _describe(errors: Sequence[ErrorDetails], config: Path | None) -> str:
    """Every mistake in one line, grouped by where it came from (the file, a variable)."""
    by_source: dict[str, list[tuple[str, str]]] = {}
    for (field, msg), e in zip(field_errors(errors, hide=CAMERA_KINDS), errors, strict=True):
        by_source.setdefault(_source_of(tuple(e["loc"]), config), []).append((field, msg))
    return "; ".join(f"{source}: {describe_field_errors(found)}" for source, found in by_source.items())


def settings_summary(settings: Settings) -> dict[str, Any]:
    """Settings as JSON without secrets (the token shows only whether one is set)."""
    doc = settings.model_dump(mode="json", exclude={"server": {"api_token"}})
    doc["server"]["api_token_set"] = settings.server.api_token is not None
    return doc
