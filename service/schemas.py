"""Request and response models of the HTTP API (also the typed results of ``RigClient``)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any, Literal, Optional, get_args, get_origin

from annotated_types import MultipleOf
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, create_model, field_validator

from rig.capture.faults import Fault
from rig.counters import CounterSpec, CounterValue, Group, Kind, counters_of
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams
from service.recordings import NAME_PATTERN, validate_name

__all__ = [
    "BODY_ERRORS",
    "CalibrationModel",
    "CameraCalibrationModel",
    "CameraHealthBase",
    "CameraHealthModel",
    "CameraInfoModel",
    "ConfigModel",
    "ConfigPatch",
    "CounterModel",
    "ErrorModel",
    "FaultRequest",
    "HealthModel",
    "HostModel",
    "PairingHealthBase",
    "PairingHealthModel",
    "ProbeModel",
    "RecordingInfo",
    "RecordingStart",
    "RectificationHealthBase",
    "RectificationHealthModel",
    "RectifiedPairModel",
    "ServerPublicModel",
    "StereoPatch",
    "WorkerHealthBase",
    "WorkerHealthModel",
]


class ErrorModel(BaseModel):
    detail: Any = Field(description="what went wrong (a string, or FastAPI's list of validation errors)")


#: Statuses every endpoint with a JSON body or the bearer token can answer with.
BODY_ERRORS: dict[int | str, dict[str, Any]] = {
    400: {"model": ErrorModel, "description": "body is not valid JSON / invalid Content-Length"},
    401: {"model": ErrorModel, "description": "missing or wrong bearer token"},
    413: {"model": ErrorModel, "description": "body larger than server.max_body_bytes"},
    422: {"model": ErrorModel, "description": "invalid parameters"},
}


class RosTime(BaseModel):
    sec: int
    nanosec: int


class RosHeader(BaseModel):
    stamp: RosTime = Field(description="capture time of the latest depth frame (0 before the first)")
    frame_id: str


class RosRegionOfInterest(BaseModel):
    x_offset: int
    y_offset: int
    height: int
    width: int
    do_rectify: bool


class CameraInfoModel(BaseModel):
    """ROS 2 ``sensor_msgs/msg/CameraInfo`` as JSON (``k``, ``r`` row-major 3×3, ``p`` 3×4)."""

    header: RosHeader
    height: int
    width: int
    distortion_model: str = Field(
        description="equidistant (Kannala-Brandt), plumb_bob, latlon (the lat-lon rectified pair), "
        "or our model's name"
    )
    d: list[float]
    k: list[float] = Field(min_length=9, max_length=9)
    r: list[float] = Field(min_length=9, max_length=9)
    p: list[float] = Field(min_length=12, max_length=12)
    binning_x: int
    binning_y: int
    roi: RosRegionOfInterest


class ProbeModel(BaseModel):
    status: Literal["ok", "ready", "not ready", "down"]
    detail: str | None = None


class _CounterFields(BaseModel):
    """A health model whose figures are generated from :mod:`rig.counters`."""

    if TYPE_CHECKING:  # the generated fields, for the type checker

        def __getattr__(self, name: str) -> CounterValue: ...


def _counter_field(spec: CounterSpec) -> tuple[Any, Any]:
    optional: Any = Optional
    annotation = optional[spec.value] if spec.optional else spec.value
    description = f"{spec.help} ({spec.kind}, {spec.unit})"
    return annotation, Field(
        description=description,
        json_schema_extra={"x-kind": spec.kind, "x-unit": spec.unit, "x-metric": spec.metric_selector},
    )


def _with_counters(base: type[_CounterFields], group: Group, doc: str) -> Any:
    """``base`` plus one field per counter of ``group`` in the table, in table order."""
    taken = set(base.model_fields) & {c.name for c in counters_of(group)}
    if taken:
        raise ValueError(f"rig.counters ({group}) redeclares {sorted(taken)} of {base.__name__}")
    fields: dict[str, Any] = {c.name: _counter_field(c) for c in counters_of(group)}
    name = base.__name__.removesuffix("Base") + "Model"
    return create_model(name, __base__=base, __doc__=doc, __module__=__name__, **fields)


class CameraHealthBase(_CounterFields):
    name: str
    kind: str
    device: str
    state: str = Field(description="starting, available, unavailable, ended or stopped")
    reason: str | None = Field(description="why the camera is not available")
    degraded_reason: str | None = Field(
        description="what is wrong with an available camera's frames: corrupt, undecodable or dropped "
        "frames above a share of cameras.supervisor's limits over its rate window"
    )
    nominal_fps: float | None
    last_seq: int | None
    last_error: str | None
    format: str
    width: int
    height: int


class WorkerHealthBase(_CounterFields):
    last_error: str | None
    last_seq: int | None
    stage_ms: dict[str, float] = Field(description="mean time per pipeline stage over the recent frames")


class PairingHealthBase(_CounterFields):
    skew_gate_ms: float = Field(description="frames further apart than this are not paired")


class RectificationHealthBase(_CounterFields):
    state: Literal["waiting", "ok", "not enough matches", "degraded"] = Field(
        description="the rectification measured from the frames (docs/rectification.md): degraded "
        "when over its bound; 'not enough matches' is no verdict"
    )
    reason: str | None = Field(description="why degraded, or why there is no measurement")
    auto_refine: bool = Field(description="online corrections on (rectification.auto_refine)")
    refinement: str | None = Field(description="what the online refinement did last, or why it did not")
    measured_age_s: float | None = Field(description="age of the last check with enough matches")
    check_wall_ms: float | None = Field(description="wall time of the last check (a low-priority thread)")


# Generated from the table (rig.counters) when this module is imported, so the OpenAPI document
# describes every figure; a test that extends the table does so before importing the service.
if TYPE_CHECKING:
    CameraHealthModel = CameraHealthBase
    WorkerHealthModel = WorkerHealthBase
    PairingHealthModel = PairingHealthBase
    RectificationHealthModel = RectificationHealthBase
else:
    CameraHealthModel = _with_counters(CameraHealthBase, "camera", "One camera's state and figures.")
    WorkerHealthModel = _with_counters(WorkerHealthBase, "worker", "The depth worker's figures.")
    PairingHealthModel = _with_counters(PairingHealthBase, "pairing", "Stereo pairing's figures.")
    RectificationHealthModel = _with_counters(
        RectificationHealthBase, "rectification", "The rectified pair's measured vertical disparity."
    )


class CounterModel(BaseModel):
    """One entry of the counter table (``rig.counters``): what a ``/health`` figure means and
    where ``/metrics`` and the dashboard show it."""

    name: str = Field(description="field name in its /health group")
    group: Group
    kind: Kind = Field(description="counter (only grows) or gauge (a current value)")
    unit: str
    help: str
    metric: str = Field(description="Prometheus sample name (counters end in _total)")
    metric_labels: dict[str, str] = Field(description="the sample's fixed labels (besides camera)")
    metric_scale: float = Field(description="the sample is the /health value times this")
    sum_of: list[str] = Field(description="a counter that is the sum of these others")
    column: str | None = Field(
        description="the dashboard's camera-table column showing it (a column sums its counters)"
    )
    digits: int = Field(description="decimals the dashboard shows")

    @classmethod
    def of(cls, spec: CounterSpec) -> CounterModel:
        return cls(
            name=spec.name,
            group=spec.group,
            kind=spec.kind,
            unit=spec.unit,
            help=spec.help,
            metric=spec.metric_sample,
            metric_labels=dict(spec.metric_labels),
            metric_scale=spec.metric_scale,
            sum_of=list(spec.sum_of),
            column=spec.column,
            digits=spec.digits,
        )


class HostModel(BaseModel):
    cpu_temp_c: float | None = Field(description="hottest CPU thermal zone; null where the board has none")
    load_avg: tuple[float, float, float] | None
    cpu_count: int | None
    disk_free_bytes: int | None = Field(description="free space where recordings go")
    disk_path: str


class RecordingInfo(BaseModel):
    name: str
    path: str
    active: bool
    pairs: int
    bytes: int | None = Field(
        description="bytes on disk; null for a recording that was not stopped cleanly (the listing "
        "reads what recordings noted, it does not walk their files)"
    )
    dropped: int = Field(description="pairs the writer could not keep up with (queue full)")
    started_at: str | None
    stopped_at: str | None
    error: str | None = Field(
        description="what went wrong: the writer's error, or why the recording's recording.json "
        "cannot be read (a field of the wrong kind is left out)"
    )


class PairHealthModel(BaseModel):
    cameras: tuple[str, str] = Field(description="the pair's left and right camera")
    baseline_m: float
    seq: int | None = Field(description="the latest published set's seq; null before the first")
    valid_fraction: float | None = Field(description="the share of the pair's pixels with depth on that set")


class HealthModel(BaseModel):
    status: Literal["ok", "degraded", "down"]
    reasons: list[str]
    uptime_s: float
    cameras: dict[str, CameraHealthModel]
    worker: WorkerHealthModel
    pairing: PairingHealthModel
    host: HostModel
    recording: RecordingInfo | None
    rectification: RectificationHealthModel | None = Field(
        None, description="null while rectification.enabled is false"
    )
    pairs: dict[str, PairHealthModel] | None = Field(
        None, description="a rig of N cameras: each stereo pair (A-B) on the latest set; null for two cameras"
    )


class RectifiedPairModel(BaseModel):
    projection: Literal["pinhole", "latlon"] = Field(
        description="pinhole: u = cx + fx·x/z, v = cy + fy·y/z; latlon: u = cx + fx·asin(x/|p|), "
        "v = cy + fy·atan2(y, z) (fx, fy in px per radian), in the left rectified frame"
    )
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float
    left: str = Field(description="the rig camera of the left image")
    right: str = Field(description="the rig camera of the right image")
    hfov_deg: float | None = Field(description="the pinhole pair's horizontal field of view (None: lat-lon)")
    px_per_deg: float | None = Field(description="the lat-lon pair's resolution (None: pinhole)")
    yaw_deg: float
    pitch_deg: float
    R_rig_vpc: list[list[float]] = Field(description="the left rectified frame's axes in the rig frame")
    T_rig_vpc: dict[str, list[list[float]]]


class CameraCalibrationModel(BaseModel):
    model: str
    width: int
    height: int
    params: dict[str, float]
    fov_deg: float | None = None
    T_rig_cam: list[list[float]]
    footprint: list[tuple[float, float]] = Field(
        description="the rectified view's border traced in this fisheye image (px)"
    )
    valid_fraction: float | None = Field(description="share of the rectified view's pixels this lens sees")


class CalibrationModel(BaseModel):
    cameras: dict[str, CameraCalibrationModel]
    vpc: RectifiedPairModel = Field(
        description="the rectified pair in effect (named vpc since its first version)"
    )
    baseline_m: float
    depth_scale_m: float
    source: str | None


class ServerPublicModel(BaseModel):
    host: str
    port: int
    depth_scale_m: float
    jpeg_quality: int
    stream_fps: float
    cors_origins: list[str]
    max_body_bytes: int
    recordings_dir: str
    api_token_set: bool


class ConfigModel(BaseModel):
    revision: int = Field(description="the configuration's revision, also the ETag: one more at each change")
    stereo: StereoParams = Field(description="the stereo parameters in effect")
    nearest_range_m: float = Field(
        description="the nearest range straight ahead the search reaches (stereo.min_range_m widens it)"
    )
    rectified: RectifiedPairModel = Field(
        description="the rectified pair in effect: projection and real size"
    )
    vpc: RectifiedPairConfig = Field(
        description="the rectified pair as configured (settings section 'rectified', first named 'vpc')"
    )
    server: ServerPublicModel
    cameras: dict[str, Any] | None


def _reject_bool(value: Any) -> Any:
    # JSON true/false equal 1/0 in Python; for a number or a Literal[0, 3, 5] they are no numbers.
    if isinstance(value, bool):
        raise ValueError("must be a number, not a boolean")
    return value


def _json_integer(value: Any) -> Any:
    # JSON Schema's "integer" is any number without a fraction: 7.0 is 7 (strict int refuses it).
    value = _reject_bool(value)
    return int(value) if isinstance(value, float) and value.is_integer() else value


def _is_integer_field(annotation: Any) -> bool:
    args = get_args(annotation) if get_origin(annotation) is Literal else ()
    return annotation is int or (bool(args) and all(type(a) is int for a in args))


# StereoParams checks these in a model validator; stated per field so the schema says it too.
def _odd() -> Any:
    """A field's constraint, for its JSON schema: the value is odd."""
    return Field(json_schema_extra={"not": {"multipleOf": 2}})


_EXTRA_CONSTRAINTS: dict[str, list[Any]] = {
    "disparity_range": [MultipleOf(16)],
    "correlation_window_size": [_odd()],
    "prefilter_size": [_odd()],
    "subpixel_window": [_odd()],
}


def _optional_fields(model: type[BaseModel]) -> dict[str, Any]:
    annotated: Any = Annotated  # built at runtime from each field's own constraints
    optional: Any = Optional
    fields: dict[str, Any] = {}
    for name, info in model.model_fields.items():
        inner: Any = info.annotation
        metadata = [*info.metadata, *_EXTRA_CONSTRAINTS.get(name, [])]
        if inner is not bool:
            metadata.append(BeforeValidator(_json_integer if _is_integer_field(inner) else _reject_bool))
        if metadata:
            inner = annotated[(inner, *metadata)]
        fields[name] = (optional[inner], Field(None, description=info.description))
    return fields


#: Every StereoParams field, optional: the fields given replace the current ones. Strict, as
#: the schema says (JSON 0 is not false), and finite; the merged set is validated again as
#: StereoParams.
StereoPatch: Any = create_model(
    "StereoPatch",
    __config__=ConfigDict(extra="forbid", strict=True, allow_inf_nan=False),
    **_optional_fields(StereoParams),
)


class ConfigPatch(BaseModel):
    model_config = ConfigDict(extra="forbid")

    stereo: StereoPatch = Field(
        description="stereo parameters to change (rig.stereo.StereoParams names); absent or null = keep"
    )


class RecordingStart(BaseModel):
    # The name pattern has a lookahead (no ".."), which pydantic's default Rust engine lacks.
    model_config = ConfigDict(extra="forbid", regex_engine="python-re")

    name: str = Field(pattern=NAME_PATTERN, description="directory name under server.recordings_dir")

    @field_validator("name")
    @classmethod
    def _plain_name(cls, v: str) -> str:
        return validate_name(v)


class FaultRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")

    fault: Fault
