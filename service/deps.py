"""FastAPI dependencies shared by the routes (``Annotated`` aliases, as the routes use them).

They are ``async`` on purpose: they only read attributes, and FastAPI would run a plain ``def``
dependency in the thread pool, one thread hop per dependency per request.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

from fastapi import Depends, Request
from starlette.concurrency import run_in_threadpool

from rig.capture.capture import CAMERA_NAMES
from service.errors import NotReady, UnknownCamera
from service.runtime import Runtime
from service.settings import Settings
from service.store import PublishedResult

__all__ = [
    "BINARY",
    "ResultDep",
    "RuntimeDep",
    "SettingsDep",
    "binary_response_doc",
    "cached_body",
    "check_camera",
    "frame_body",
    "frame_headers",
    "not_found_doc",
]

BINARY = {"schema": {"type": "string", "format": "binary"}}
_ERROR_REF = {"type": "object", "properties": {"detail": {}}, "required": ["detail"]}
_HEADER_DOCS = {
    "X-Frame-Seq": {
        "description": "sequence number of the pair (left camera)",
        "schema": {"type": "integer"},
    },
    "X-Timestamp-Ns": {"description": "capture time, CLOCK_MONOTONIC ns", "schema": {"type": "integer"}},
}


def not_found_doc(description: str) -> dict[int | str, Any]:
    """OpenAPI ``responses`` entry of a 404 with its JSON ``detail``."""
    return {404: {"description": description, "content": {"application/json": {"schema": _ERROR_REF}}}}


def binary_response_doc(
    description: str, *media_types: str, scale_header: str | None = None, not_found: str | None = None
) -> dict[int | str, Any]:
    """OpenAPI ``responses`` for an endpoint serving the latest frame as bytes; ``scale_header``:
    the name of its metres-per-unit header (``X-Depth-Scale``, ``X-Range-Scale``); ``not_found``:
    when it may answer 404, what that means."""
    headers = dict(_HEADER_DOCS)
    if scale_header is not None:
        headers[scale_header] = {
            "description": "metres per unit of the body (1 for npy, which is in metres)",
            "schema": {"type": "number"},
        }
    return {
        200: {"description": description, "content": {m: BINARY for m in media_types}, "headers": headers},
        503: {"description": "no depth frame yet", "content": {"application/json": {"schema": _ERROR_REF}}},
        **(not_found_doc(not_found) if not_found is not None else {}),
    }


async def get_runtime(request: Request) -> Runtime:
    runtime: Runtime | None = getattr(request.app.state, "runtime", None)
    if runtime is None:
        raise NotReady("the service is starting")
    return runtime


async def get_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


async def latest_result(runtime: Annotated[Runtime, Depends(get_runtime)]) -> PublishedResult:
    result = runtime.store.latest
    if result is None:
        raise NotReady("no depth frame yet: the pipeline has not processed a pair")
    return result


def check_camera(camera: str) -> None:
    """UnknownCamera (404) unless ``camera`` is one of the rig's."""
    if camera not in CAMERA_NAMES:
        raise UnknownCamera(f"unknown camera {camera!r}; cameras: {', '.join(CAMERA_NAMES)}")


RuntimeDep = Annotated[Runtime, Depends(get_runtime)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
ResultDep = Annotated[PublishedResult, Depends(latest_result)]


def frame_headers(result: PublishedResult, **extra: str) -> dict[str, str]:
    return {
        "X-Frame-Seq": str(result.seq),
        "X-Timestamp-Ns": str(result.ts_ns),
        "X-Age-Ms": f"{result.age_ms:.2f}",
        "X-Latency-Ms": f"{result.age_ms:.2f}",  # X-Age-Ms under its first name
        "Cache-Control": "no-store",
        **extra,
    }


async def frame_body(runtime: Runtime, result: PublishedResult, key: str) -> bytes:
    """:func:`cached_body` of one of the runtime's frame bodies (``runtime.frame_bodies[key]``),
    the table the worker prefetches from."""
    produce = runtime.frame_bodies[key]
    return await cached_body(result, key, lambda: produce(result))


async def cached_body(result: PublishedResult, key: str, produce: Callable[[], bytes]) -> bytes:
    """The encoded body for ``key``: cached bytes at once, else encoded in a worker thread (the
    event loop never encodes) — once per frame, whoever asks first."""
    body = result.cache.peek(key)
    if body is not None:
        return body
    return await run_in_threadpool(result.cache.get, key, produce)
