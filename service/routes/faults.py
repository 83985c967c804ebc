"""``POST /cameras/{camera}/faults``: inject a fault into a file-backed camera of the running
service (reliability tests, demos). Mounted only with ``server.fault_injection: true``; needs the
bearer token like every state-changing endpoint."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path

from rig.capture.capture import CAMERA_NAMES
from rig.errors import ConfigError
from service.deps import RuntimeDep
from service.schemas import BODY_ERRORS, ErrorModel, FaultRequest
from service.security import AuthDep, TokenFirstRoute

__all__ = ["router"]

router = APIRouter(tags=["faults"], route_class=TokenFirstRoute)


@router.post(
    "/cameras/{camera}/faults",
    status_code=202,
    summary="Inject a fault into a file camera (rig.capture.faults)",
    responses={**BODY_ERRORS, 404: {"model": ErrorModel}, 409: {"model": ErrorModel}},
)
def inject_fault(
    body: FaultRequest, runtime: RuntimeDep, _auth: AuthDep, camera: Annotated[str, Path()]
) -> dict[str, Any]:
    if camera not in CAMERA_NAMES:
        raise HTTPException(404, f"unknown camera {camera!r}; cameras: {', '.join(CAMERA_NAMES)}")
    try:
        runtime.capture.inject(camera, body.fault)
    except ConfigError as err:
        raise HTTPException(409, str(err)) from err
    return {"camera": camera, "fault": body.fault.model_dump(mode="json")}
