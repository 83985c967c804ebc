"""The FastAPI application factory.

``create_app(settings)`` builds the app object only; the runtime (calibration, LUTs, cameras,
worker) is built and started in the lifespan, or handed in ready-built (``rig serve`` builds it
first so a bad configuration is one line before the server starts), and stopped at shutdown.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.middleware.cors import CORSMiddleware
from starlette.concurrency import run_in_threadpool
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.error_handlers import install_error_handlers
from service.fast_path import answer_hot_request
from service.foxglove import FoxgloveLive, start_foxglove
from service.routes import (
    calibration,
    camera_info,
    config,
    counters,
    dashboard,
    depth,
    docs,
    faults,
    frames,
    health,
    metrics,
    readout,
    recordings,
    ring,
    stream,
)
from service.runtime import Runtime
from service.schemas import HealthModel
from service.security import BodySizeLimit
from service.settings import Settings, load_settings

__all__ = ["API_VERSION", "DepthServiceApp", "FastPath", "create_app"]

log = logging.getLogger("service.app")

API_VERSION = "1"


class DepthServiceApp(FastAPI):
    """FastAPI, except that a HEAD is answered as its GET without the body (wherever GET works),
    and that the hot requests (polls of ``/depth`` and ``/disparity`` whose body the worker
    already encoded, of ``/health`` while its shared document is fresh) are answered ahead of
    FastAPI's routing by :class:`FastPath`. ``fast_path_on`` False sends every request to the
    routes."""

    fast_path_on = True

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] == "HEAD":
            await self.__call__({**scope, "method": "GET"}, receive, _headers_only(send))
            return
        await super().__call__(scope, receive, send)


class FastPath:
    """The hot requests answered without FastAPI's routing, dependencies and response objects
    (:mod:`service.fast_path`), as the app's innermost middleware: every middleware the app has,
    or is given later, wraps it, so the answers it gives pass through them as the routes' do."""

    def __init__(self, app: ASGIApp, owner: DepthServiceApp) -> None:
        self.app = app
        self.owner = owner

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if self.owner.fast_path_on and await answer_hot_request(self.owner.state, scope, send):
            return
        await self.app(scope, receive, send)


def _headers_only(send: Send) -> Send:
    """``send`` for a HEAD answered as its GET: the status and headers, then an empty body at once
    (the server then reports the request complete, which ends a stream); later body parts are
    dropped."""
    started = False

    async def send_head(message: Message) -> None:
        nonlocal started
        if message["type"] != "http.response.start":
            return
        if not started:
            started = True
            await send(message)
            await send({"type": "http.response.body", "body": b"", "more_body": False})

    return send_head


def create_app(settings: Settings | None = None, *, runtime: Runtime | None = None) -> FastAPI:
    """The depth service app for ``settings`` (default: :func:`load_settings`). A given
    ``runtime`` is started at startup and stopped at shutdown (ownership passes to the app)."""
    settings = settings if settings is not None else load_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        rt = runtime if runtime is not None else await run_in_threadpool(Runtime.build, settings)
        app.state.runtime = rt
        await run_in_threadpool(rt.start)
        fox: FoxgloveLive | None = None
        try:
            if settings.server.foxglove.enabled:
                fox = await run_in_threadpool(
                    start_foxglove,
                    rt,
                    lambda: health.health_body(rt, settings)[0],
                    HealthModel.model_json_schema(),
                )
            app.state.foxglove = fox
            yield
        finally:
            if fox is not None:
                await run_in_threadpool(fox.stop)
            await run_in_threadpool(rt.stop)
            log.info("stopped: depth worker and camera threads joined")

    app = DepthServiceApp(
        title="odfc-rig depth service",
        version=API_VERSION,
        description="Depth from an orthogonally divergent fisheye stereo rig: depth maps, frames, "
        "point clouds, health and metrics. State-changing endpoints need `Authorization: Bearer <token>`.",
        lifespan=lifespan,
        docs_url=None,  # served from the package instead of a CDN: routes.docs
        redoc_url=None,
    )
    app.state.settings = settings
    app.state.runtime = None
    app.state.foxglove = None

    for module in (
        health,
        counters,
        depth,
        ring,
        readout,
        stream,
        frames,
        calibration,
        camera_info,
        config,
        recordings,
        metrics,
        dashboard,
    ):
        app.include_router(module.router)
    if settings.server.fault_injection:
        app.include_router(faults.router)
    docs.add_api_docs(app)

    install_error_handlers(app)

    # Added first = innermost: every middleware added after it (here or by an embedding
    # application) also applies to the requests it answers.
    app.add_middleware(FastPath, owner=app)
    # Added last = outermost: oversized bodies are refused before anything else reads them.
    if settings.server.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.server.cors_origins,
            allow_methods=["GET", "POST", "PATCH"],
            allow_headers=["Authorization", "Content-Type"],
            expose_headers=["X-Frame-Seq", "X-Timestamp-Ns", "X-Depth-Scale", "X-Age-Ms", "X-Latency-Ms"],
        )
    app.add_middleware(BodySizeLimit, max_bytes=settings.server.max_body_bytes)
    return app
