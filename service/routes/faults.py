"""``POST /cameras/{camera}/faults``: inject a fault into a file-backed camera of the running
service (reliability tests, demos). Mounted only with ``server.fault_injection: true``; needs the
bearer token like every state-changing endpoint."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path

from service.deps import RuntimeDep, check_camera
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
    check_camera(camera)
    runtime.capture.inject(camera, body.fault)  # FaultNotSupported (409) for a V4L2 camera
    return {"camera": camera, "fault": body.fault.model_dump(mode="json")}
