"""The HTTP API's one error mapping: every project exception a route raises becomes a status
code and a JSON ``{"detail": ...}`` here, and nowhere else.

The most specific class listed wins (``DiskFullError`` before ``RigError``). Client mistakes
are 4xx; a fault on the server's side (a disk that fails, a calibration that cannot be used)
is 5xx and logged. Anything that is not a project exception is a bug: 500 with only its type
in ``detail``, and the traceback in the log.
"""

from __future__ import annotations

import logging
import math
import re
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import compile_path

from calibration.errors import CalibrationError
from rig.errors import ConfigError, DiskFullError, FaultNotSupported, RigError
from service.errors import (
    ConfidenceOff,
    ConfigChanged,
    NotFound,
    NotReady,
    RecordingConflict,
    RecordingNameError,
    RecordingStorageError,
    ServiceError,
    StereoParamsRefused,
    TooManyStreams,
    Unauthorized,
)

__all__ = [
    "HEADERS_BY_ERROR",
    "STATUS_BY_ERROR",
    "error_detail",
    "error_response",
    "install_error_handlers",
    "json_safe",
    "status_for",
]

log = logging.getLogger("service.app")

#: Project exception → HTTP status (the most specific listed base class of an exception applies).
STATUS_BY_ERROR: dict[type[Exception], int] = {
    # service
    NotFound: 404,  # RecordingNotFound, UnknownCamera, a dashboard asset
    RecordingNameError: 422,
    RecordingConflict: 409,
    ConfidenceOff: 409,
    ConfigChanged: 412,
    StereoParamsRefused: 422,
    NotReady: 503,
    RecordingStorageError: 500,  # server.recordings_dir unusable: the operator's to fix
    TooManyStreams: 503,
    Unauthorized: 401,
    ServiceError: 500,
    # rig
    FaultNotSupported: 409,
    ConfigError: 422,
    DiskFullError: 507,
    RigError: 500,
    # calibration (the rig's own calibration: never the client's doing)
    CalibrationError: 500,
}


#: Headers that go with an error's response.
HEADERS_BY_ERROR: dict[type[Exception], dict[str, str]] = {Unauthorized: {"WWW-Authenticate": "Bearer"}}


def status_for(err: BaseException) -> int:
    """The status :data:`STATUS_BY_ERROR` gives ``err`` (500 for anything not listed)."""
    for cls in type(err).__mro__:
        status = STATUS_BY_ERROR.get(cls)
        if status is not None:
            return status
    return 500


def error_detail(err: BaseException) -> Any:
    """The ``detail`` of ``err``'s JSON body: its own ``detail`` if it carries one, else its message."""
    detail = getattr(err, "detail", None)
    return detail if detail is not None else str(err)


def json_safe(value: Any) -> Any:
    """``value`` with NaN and ±infinity as the strings ``"NaN"``, ``"Infinity"``, ``"-Infinity"``:
    a refused request may have sent them (Python's JSON reads them, and ``1e400`` as infinity),
    and an error that quotes its input must still be valid JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value


def error_response(exc: Exception) -> JSONResponse:
    """The answer to a project exception (for a response that must refuse from inside itself)."""
    headers = next((h for cls, h in HEADERS_BY_ERROR.items() if isinstance(exc, cls)), None)
    return JSONResponse(
        {"detail": json_safe(error_detail(exc))}, status_code=status_for(exc), headers=headers
    )


async def invalid_request(request: Request, exc: Exception) -> JSONResponse:
    """FastAPI's 422 for a request that fails validation, with every field error listed."""
    assert isinstance(exc, RequestValidationError)
    detail = jsonable_encoder(exc.errors())
    return JSONResponse({"detail": json_safe(detail)}, status_code=422)


async def project_error(request: Request, exc: Exception) -> JSONResponse:
    response = error_response(exc)
    if response.status_code >= 500 and not isinstance(exc, TooManyStreams):  # a load, not a fault
        log.error("%s %s: %s", request.method, request.url.path, exc)
    return response


async def internal_error(request: Request, exc: Exception) -> JSONResponse:
    log.exception("%s %s failed", request.method, request.url.path)
    return JSONResponse({"detail": f"internal error: {type(exc).__name__}"}, status_code=500)


def _documented_methods(app: FastAPI, path: str) -> set[str]:
    """HTTP methods the OpenAPI document lists for the path template matching ``path``."""
    table: list[tuple[re.Pattern[str], set[str]]] | None = getattr(app.state, "allow_table", None)
    if table is None:
        table = [
            (compile_path(template)[0], {m.upper() for m in ops})
            for template, ops in app.openapi().get("paths", {}).items()
        ]
        app.state.allow_table = table
    methods = {m for regex, methods in table if regex.match(path) for m in methods}
    return methods | {"HEAD"} if "GET" in methods else methods  # HEAD: see service.app


async def http_error(request: Request, exc: Exception) -> Response:
    """Starlette's HTTP errors (404 for an unknown URL, 405, 413) as FastAPI answers them,
    with ``Allow`` listing every documented method of the path on a 405."""
    assert isinstance(exc, StarletteHTTPException)
    response = await http_exception_handler(request, exc)
    if exc.status_code == 405:
        # Each method is its own route: list every documented method of the path.
        methods = _documented_methods(request.app, request.url.path)
        if methods:
            response.headers["Allow"] = ", ".join(sorted(methods))
    return response


def install_error_handlers(app: FastAPI) -> None:
    """Register the mapping on ``app``."""
    app.add_exception_handler(StarletteHTTPException, http_error)
    app.add_exception_handler(RequestValidationError, invalid_request)
    for cls in (ServiceError, RigError, CalibrationError):
        app.add_exception_handler(cls, project_error)
    app.add_exception_handler(Exception, internal_error)
