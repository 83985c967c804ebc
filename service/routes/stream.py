"""``/stream.mjpg``: colourised depth as multipart/x-mixed-replace (an ``<img>`` plays it).

Each part carries the frame's headers (``X-Frame-Seq``, ``X-Timestamp-Ns``) and its timings
(``X-Age-Ms`` arrival → published, also as ``X-Latency-Ms``, its first name; ``X-Processing-Ms``
and one ``X-Timing-<stage>-Ms`` per pipeline stage). Parts are the cached JPEG of each new
frame, at most ``server.stream_fps`` a second.

A slow reader gets the newest frame when it is ready for one, never a queue of old ones: the
connection buffers about one part (the kernel's send buffer is :data:`SEND_BUFFER_BYTES`, and
nothing more is written while any of the last part is unsent), and the frame of the next part is
chosen only once the client has taken the previous one. A client that has not taken a part
within ``server.stream_stall_s`` is dropped; a stream holds no frame, only the bytes of its last
part in the connection's buffers. At most ``server.max_streams`` streams run at once (503 beyond).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import Annotated, Any

from fastapi import APIRouter, Query
from starlette.responses import Response
from starlette.types import Receive, Scope, Send

from service.connections import TransportControl, transport_control
from service.deps import RuntimeDep
from service.error_handlers import error_response
from service.errors import TooManyStreams
from service.routes.depth import colorized_body
from service.runtime import Runtime
from service.store import PublishedResult

__all__ = ["BOUNDARY", "SEND_BUFFER_BYTES", "router"]

log = logging.getLogger("service.stream")

router = APIRouter(tags=["depth"])

BOUNDARY = "frame"
#: SO_SNDBUF asked for a stream's socket (the kernel doubles it): less than one part at 640x480.
SEND_BUFFER_BYTES = 16 * 1024
_IDLE_POLL_S = 0.02
_MEDIA_TYPE = f"multipart/x-mixed-replace; boundary={BOUNDARY}"


def _part_head(result: PublishedResult, length: int) -> bytes:
    lines = [
        f"--{BOUNDARY}",
        "Content-Type: image/jpeg",
        f"Content-Length: {length}",
        f"X-Frame-Seq: {result.seq}",
        f"X-Timestamp-Ns: {result.ts_ns}",
        f"X-Age-Ms: {result.age_ms:.2f}",
        f"X-Latency-Ms: {result.age_ms:.2f}",
        f"X-Processing-Ms: {result.frame.timings_ms.get('total', 0.0):.2f}",
    ]
    lines += [f"X-Timing-{stage.capitalize()}-Ms: {ms:.2f}" for stage, ms in result.frame.timings_ms.items()]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("ascii")


class MjpegStream(Response):
    """The stream as an ASGI response (see module doc); ``max_frames`` ends it after that many parts."""

    media_type = _MEDIA_TYPE

    def __init__(self, runtime: Runtime, max_frames: int | None) -> None:
        # Not Response.__init__: that would declare the empty body's Content-Length.
        self.status_code = 200
        self.background = None
        # A stream connection is not reused: its buffers are sized for one stream part.
        self.init_headers({"Cache-Control": "no-store", "X-Accel-Buffering": "no", "Connection": "close"})
        self.runtime = runtime
        self.max_frames = max_frames

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        runtime = self.runtime
        try:
            runtime.open_stream()
        except TooManyStreams as busy:
            await error_response(busy)(scope, receive, send)
            return
        gone = asyncio.Event()
        watcher = asyncio.get_running_loop().create_task(_watch_disconnect(receive, gone))
        try:
            await send({"type": "http.response.start", "status": 200, "headers": self.raw_headers})
            if await self._parts(send, transport_control(scope), gone):
                await send({"type": "http.response.body", "body": b""})
        finally:
            runtime.close_stream()
            watcher.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await watcher

    async def _parts(self, send: Send, control: TransportControl | None, gone: asyncio.Event) -> bool:
        """Send parts until ``max_frames`` (True) or the client leaves or stalls (False)."""
        runtime = self.runtime
        settings = runtime.settings.server
        period = 1.0 / settings.stream_fps
        loop = asyncio.get_running_loop()
        if control is not None:
            control.limit_buffering(SEND_BUFFER_BYTES)
        last = sent = 0
        while self.max_frames is None or sent < self.max_frames:
            if not await _newer_than(runtime, last, gone):
                return False
            # The client has taken the previous part before the frame of this one is chosen.
            if control is not None and not await control.writable(settings.stream_stall_s):
                log.info("dropped a /stream.mjpg client: a part not taken in %g s", settings.stream_stall_s)
                control.abort()
                return False
            started = loop.time()
            part = await _part(runtime)
            last = part[0]
            sent += 1
            await send({"type": "http.response.body", "body": part[1], "more_body": True})
            del part
            await asyncio.sleep(max(0.0, period - (loop.time() - started)))
        return True


async def _watch_disconnect(receive: Receive, gone: asyncio.Event) -> None:
    while (await receive())["type"] != "http.disconnect":
        pass
    gone.set()


async def _newer_than(runtime: Runtime, index: int, gone: asyncio.Event) -> bool:
    """Wait for a result newer than ``index``; False if the client left first."""
    while not gone.is_set():
        result = runtime.store.latest
        if result is not None and result.index > index:
            return True
        await asyncio.sleep(_IDLE_POLL_S)
    return False


async def _part(runtime: Runtime) -> tuple[int, bytes]:
    """The newest result's index and its part (the stream keeps the bytes, not the frame)."""
    result = runtime.store.latest
    assert result is not None
    body = await colorized_body(runtime, result)
    return result.index, _part_head(result, len(body)) + body + b"\r\n"


@router.get(
    "/stream.mjpg",
    response_class=MjpegStream,
    status_code=200,
    summary="Live colourised depth (MJPEG over multipart/x-mixed-replace)",
    responses={
        200: {"content": {_MEDIA_TYPE: {}}},
        503: {"description": "server.max_streams clients are streaming already"},
    },
)
async def stream(
    runtime: RuntimeDep,
    max_frames: Annotated[
        int | None, Query(ge=1, le=1_000_000, description="end after this many parts")
    ] = None,
) -> Any:
    return MjpegStream(runtime, max_frames)
