"""The hot requests answered without FastAPI's request machinery.

Robot nodes poll ``GET /depth`` (or ``/disparity``) at their own rate, tens of clients at once,
and on a 2-core board every request's CPU comes out of the depth worker's frame rate. The worker
encodes the polled bodies as it publishes a frame (``DepthWorker``'s prefetch), so such a request
only has to send bytes that already exist; FastAPI's middleware stack, dependency solving and
response objects were most of its cost. :func:`serve_cached_frame` answers exactly those
requests — a plain ``GET`` of ``/depth`` or ``/disparity`` with no query or ``format=png|npy``,
no body, a published frame whose body is cached — with the response the route would give
(:func:`service.routes.depth.array_body` and :func:`service.deps.frame_headers` make both); any
other request, and any miss, goes to the app as usual.
"""

from __future__ import annotations

from typing import Any, Final

from starlette.types import Scope, Send

from service.deps import frame_headers
from service.routes.depth import ArrayEndpoint, ArrayFormat, array_body

__all__ = ["serve_cached_frame"]

_PATHS: Final[dict[str, ArrayEndpoint]] = {"/depth": "depth", "/disparity": "disparity"}
_QUERIES: Final[dict[bytes, ArrayFormat]] = {b"": "png", b"format=png": "png", b"format=npy": "npy"}
# A request that says it carries a body goes the long way (the size limit, FastAPI's reading).
_BODY_HEADERS: Final = (b"content-length", b"transfer-encoding")


async def serve_cached_frame(state: Any, scope: Scope, send: Send) -> bool:
    """Answer ``scope`` from the latest frame's cached body if it is one of the hot requests
    (see module doc); ``state`` is the app's state (``runtime``, ``settings``). True if answered."""
    if scope["type"] != "http" or scope["method"] != "GET" or scope.get("root_path"):
        return False
    endpoint = _PATHS.get(scope["path"])
    fmt = _QUERIES.get(scope["query_string"])
    if endpoint is None or fmt is None:
        return False
    for name, value in scope["headers"]:
        if name in _BODY_HEADERS and value != b"0":
            return False
    runtime = state.runtime
    result = None if runtime is None else runtime.store.latest
    if result is None:
        return False
    spec = array_body(endpoint, fmt, state.settings.server.depth_scale_m)
    body = result.cache.peek(spec.key)
    if body is None:
        return False
    extra = frame_headers(result, **spec.headers)
    headers = [
        (b"content-length", str(len(body)).encode()),
        (b"content-type", spec.media_type.encode()),
        *((name.lower().encode("latin-1"), value.encode("latin-1")) for name, value in extra.items()),
    ]
    await send({"type": "http.response.start", "status": 200, "headers": headers})
    await send({"type": "http.response.body", "body": body})
    return True
