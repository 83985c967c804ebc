"""``/stream.mjpg``: colourised depth as multipart/x-mixed-replace (an ``<img>`` plays it).

Each part carries the frame's headers (``X-Frame-Seq``, ``X-Timestamp-Ns``) and its timings
(``X-Latency-Ms`` arrival → published, ``X-Processing-Ms`` and one ``X-Timing-<stage>-Ms`` per
pipeline stage). Parts are the cached JPEG of each new frame, at most ``server.stream_fps`` a
second; a slow client simply misses frames.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import APIRouter, Query, Request
from fastapi.responses import StreamingResponse

from service.deps import RuntimeDep
from service.routes.depth import colorized_body
from service.store import PublishedResult

__all__ = ["BOUNDARY", "router"]

router = APIRouter(tags=["depth"])

BOUNDARY = "frame"
_IDLE_POLL_S = 0.02


def _part_head(result: PublishedResult, length: int) -> bytes:
    lines = [
        f"--{BOUNDARY}",
        "Content-Type: image/jpeg",
        f"Content-Length: {length}",
        f"X-Frame-Seq: {result.seq}",
        f"X-Timestamp-Ns: {result.ts_ns}",
        f"X-Latency-Ms: {result.latency_ms:.2f}",
        f"X-Processing-Ms: {result.frame.timings_ms.get('total', 0.0):.2f}",
    ]
    lines += [f"X-Timing-{stage.capitalize()}-Ms: {ms:.2f}" for stage, ms in result.frame.timings_ms.items()]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("ascii")


@router.get(
    "/stream.mjpg",
    response_class=StreamingResponse,
    summary="Live colourised depth (MJPEG over multipart/x-mixed-replace)",
    responses={200: {"content": {f"multipart/x-mixed-replace; boundary={BOUNDARY}": {}}}},
)
async def stream(
    request: Request,
    runtime: RuntimeDep,
    max_frames: Annotated[
        int | None, Query(ge=1, le=1_000_000, description="end after this many parts")
    ] = None,
) -> StreamingResponse:
    period = 1.0 / runtime.settings.server.stream_fps

    async def parts() -> AsyncIterator[bytes]:
        last = 0
        sent = 0
        loop = asyncio.get_running_loop()
        while max_frames is None or sent < max_frames:
            if await request.is_disconnected():
                return
            result = runtime.store.latest
            if result is None or result.index <= last:
                await asyncio.sleep(_IDLE_POLL_S)
                continue
            started = loop.time()
            body = await colorized_body(runtime, result)
            last = result.index
            sent += 1
            yield _part_head(result, len(body)) + body + b"\r\n"
            await asyncio.sleep(max(0.0, period - (loop.time() - started)))

    return StreamingResponse(
        parts(),
        media_type=f"multipart/x-mixed-replace; boundary={BOUNDARY}",
        headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"},
    )
