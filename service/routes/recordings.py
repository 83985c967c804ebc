"""``/recordings``: record the raw frames the service processes.

``POST /recordings {"name": N}`` starts recording into ``server.recordings_dir/N`` (201);
``POST /recordings/{name}/stop`` stops it (200, with the final counts); ``GET /recordings``
lists every recording there. One recording runs at a time; both POSTs need the bearer token.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path

from service.deps import RuntimeDep
from service.recordings import NAME_PATTERN, RecordingStatus
from service.schemas import BODY_ERRORS, ErrorModel, RecordingInfo, RecordingStart
from service.security import AuthDep, TokenFirstRoute

__all__ = ["router"]

router = APIRouter(tags=["recordings"], route_class=TokenFirstRoute)

# Documented with the pattern, checked by validate_name (422): FastAPI's parameter validation
# uses pydantic's Rust regex engine, which has no lookahead.
NameParam = Annotated[str, Path(description="recording name", json_schema_extra={"pattern": NAME_PATTERN})]


def _info(status: RecordingStatus) -> RecordingInfo:
    return RecordingInfo.model_validate(status, from_attributes=True)


@router.get("/recordings", response_model=list[RecordingInfo], summary="Recordings on this device")
def list_recordings(runtime: RuntimeDep) -> list[RecordingInfo]:
    return [_info(s) for s in runtime.recordings.list()]


@router.post(
    "/recordings",
    response_model=RecordingInfo,
    status_code=201,
    summary="Start recording the camera pairs",
    responses={
        **BODY_ERRORS,
        409: {"model": ErrorModel, "description": "the name exists, or a recording is running"},
        500: {"model": ErrorModel, "description": "server.recordings_dir cannot hold recordings"},
        507: {"model": ErrorModel, "description": "disk full"},
    },
)
def start_recording(body: RecordingStart, runtime: RuntimeDep, _auth: AuthDep) -> RecordingInfo:
    meta = {"vpc": runtime.pipeline.pair.as_json()}
    return _info(runtime.recordings.start(body.name, meta))


@router.post(
    "/recordings/{name}/stop",
    response_model=RecordingInfo,
    summary="Stop the running recording",
    responses={**BODY_ERRORS, 404: {"model": ErrorModel}},
)
def stop_recording(name: NameParam, runtime: RuntimeDep, _auth: AuthDep) -> RecordingInfo:
    return _info(runtime.recordings.stop(name))
