"""``/health``, ``/livez`` and ``/readyz``; ``/health``'s figures are those of :mod:`rig.counters`."""

from __future__ import annotations

from fastapi import APIRouter, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from rig.counters import flatten
from service.deps import RuntimeDep, SettingsDep
from service.health_report import HealthReport
from service.runtime import Runtime
from service.schemas import (
    CameraHealthModel,
    HealthModel,
    HostModel,
    PairHealthModel,
    PairingHealthModel,
    ProbeModel,
    RecordingInfo,
    RectificationHealthModel,
    WorkerHealthModel,
)
from service.settings import Settings

__all__ = ["HEALTH_MEDIA_TYPE", "fresh_health", "health_body", "health_model", "router"]

router = APIRouter(tags=["health"])

HEALTH_MEDIA_TYPE = "application/json"


def health_model(report: HealthReport) -> HealthModel:
    cams = {name: CameraHealthModel.model_validate(flatten(c)) for name, c in report.capture.cameras.items()}
    return HealthModel(
        status=report.status,
        reasons=report.reasons,
        uptime_s=report.uptime_s,
        cameras=cams,
        worker=WorkerHealthModel.model_validate(flatten(report.worker)),
        pairing=PairingHealthModel.model_validate(flatten(report.capture.pairing)),
        host=HostModel.model_validate(report.host, from_attributes=True),
        recording=None
        if report.recording is None
        else RecordingInfo.model_validate(report.recording, from_attributes=True),
        rectification=None
        if report.rectification is None
        else RectificationHealthModel.model_validate(flatten(report.rectification)),
        pairs=None
        if report.pairs is None
        else {k: PairHealthModel.model_validate(p, from_attributes=True) for k, p in report.pairs.items()},
    )


@router.get(
    "/health",
    response_model=HealthModel,
    summary="Service health: 200 ok/degraded, 503 down",
    responses={503: {"model": HealthModel, "description": "down: no camera delivers or the worker stopped"}},
)
async def get_health(runtime: RuntimeDep, settings: SettingsDep) -> Response:
    # A fresh shared document is answered on the event loop; building one reads the host's
    # state (file systems, sensors), which may block, so that runs in a thread.
    snapshot = fresh_health(runtime, settings)
    if snapshot is None:
        snapshot = await run_in_threadpool(health_body, runtime, settings)
    body, status = snapshot
    return Response(body, status_code=status, media_type=HEALTH_MEDIA_TYPE)


def fresh_health(runtime: Runtime, settings: Settings) -> tuple[bytes, int] | None:
    """The shared ``/health`` body and status if one younger than ``server.health_max_age_s``
    exists (no I/O; also answered by :mod:`service.fast_path`), else None."""
    return runtime.fresh_health_snapshot(settings.server.health_max_age_s)


def health_body(runtime: Runtime, settings: Settings) -> tuple[bytes, int]:
    """The ``/health`` body and status, shared with the requests within
    ``server.health_max_age_s`` (may read the host's state: call it off the event loop)."""
    body: tuple[bytes, int] = runtime.health_snapshot(_render, settings.server.health_max_age_s)
    return body


def _render(report: HealthReport) -> tuple[bytes, int]:
    model = health_model(report)
    return model.model_dump_json().encode(), 503 if model.status == "down" else 200


@router.get(
    "/livez",
    response_model=ProbeModel,
    summary="Liveness: 200 while the process and its depth worker run",
    responses={503: {"model": ProbeModel}},
)
async def get_livez(runtime: RuntimeDep) -> JSONResponse:
    if runtime.worker.is_alive():
        return JSONResponse({"status": "ok", "detail": None})
    return JSONResponse({"status": "down", "detail": "depth worker not running"}, status_code=503)


@router.get(
    "/readyz",
    response_model=ProbeModel,
    summary="Readiness: 200 once a depth frame has been produced",
    responses={503: {"model": ProbeModel}},
)
async def get_readyz(runtime: RuntimeDep) -> JSONResponse:
    if runtime.store.latest is not None:
        return JSONResponse({"status": "ready", "detail": None})
    return JSONResponse({"status": "not ready", "detail": "no depth frame yet"}, status_code=503)
