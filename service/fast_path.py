"""The hot requests answered without FastAPI's request machinery.

Robot nodes poll ``GET /depth`` (or ``/disparity``) and ``GET /health`` at their own rate, tens
of clients at once, and on a 2-core board every request's CPU comes out of the depth worker's
frame rate. The answers to those polls usually exist already: the worker encodes the polled
bodies as it publishes a frame (``DepthWorker``'s prefetch), and ``/health`` is one shared
document for ``server.health_max_age_s``. FastAPI's middleware stack, dependency solving and
response objects were then most of a request's cost (at 316 requests/s of ``/depth``: 116 ms of
event-loop CPU per second through FastAPI, 54 ms answered here).

:func:`answer_hot_request` answers exactly those requests — a plain ``GET`` without a body of
``/depth`` or ``/disparity`` (no query or ``format=png|npy``) whose body is cached, or of
``/health`` (no query) while its shared document is fresh — with the response the route would
give, made by the same functions (:func:`service.routes.depth.array_body`,
:func:`service.deps.frame_headers`, :func:`service.routes.health.fresh_health`). Any other
request, and any miss, goes to the app as usual.
"""

from __future__ import annotations

from typing import Any, Final

from starlette.types import Scope, Send

from service.deps import frame_headers
from service.routes.depth import ArrayEndpoint, ArrayFormat, array_body
from service.routes.health import HEALTH_MEDIA_TYPE, fresh_health

__all__ = ["answer_hot_request"]

_ARRAY_PATHS: Final[dict[str, ArrayEndpoint]] = {"/depth": "depth", "/disparity": "disparity"}
_ARRAY_QUERIES: Final[dict[bytes, ArrayFormat]] = {b"": "png", b"format=png": "png", b"format=npy": "npy"}
# A request that says it carries a body goes the long way (the size limit, FastAPI's reading).
_BODY_HEADERS: Final = (b"content-length", b"transfer-encoding")

# (status, media type, body, extra headers) of an answer.
_Answer = tuple[int, str, bytes, dict[str, str]]


async def answer_hot_request(state: Any, scope: Scope, send: Send) -> bool:
    """Answer ``scope`` if it is one of the hot requests and its answer exists (see module doc);
    ``state`` is the app's state (``runtime``, ``settings``). True if answered."""
    if scope["type"] != "http" or scope["method"] != "GET" or scope.get("root_path"):
        return False
    for name, value in scope["headers"]:
        if name in _BODY_HEADERS and value != b"0":
            return False
    runtime = state.runtime
    if runtime is None:
        return False
    path, query = scope["path"], scope["query_string"]
    answer: _Answer | None = None
    if path == "/health" and not query:
        answer = _health(runtime, state.settings)
    elif path in _ARRAY_PATHS and query in _ARRAY_QUERIES:
        answer = _array(runtime, state.settings, _ARRAY_PATHS[path], _ARRAY_QUERIES[query])
    if answer is None:
        return False
    status, media_type, body, extra = answer
    headers = [
        (b"content-length", str(len(body)).encode()),
        (b"content-type", media_type.encode()),
        *((k.lower().encode("latin-1"), v.encode("latin-1")) for k, v in extra.items()),
    ]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})
    return True


def _array(runtime: Any, settings: Any, endpoint: ArrayEndpoint, fmt: ArrayFormat) -> _Answer | None:
    result = runtime.store.latest
    if result is None:
        return None
    spec = array_body(endpoint, fmt, settings.server.depth_scale_m)
    body = result.cache.peek(spec.key)
    if body is None:
        return None
    return 200, spec.media_type, body, frame_headers(result, **spec.headers)


def _health(runtime: Any, settings: Any) -> _Answer | None:
    snapshot = fresh_health(runtime, settings)
    if snapshot is None:
        return None
    body, status = snapshot
    return status, HEALTH_MEDIA_TYPE, body, {}
