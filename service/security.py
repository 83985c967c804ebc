"""Security of the HTTP API: bearer-token check for state-changing endpoints and a request
body size limit.

Every endpoint that changes state requires ``Authorization: Bearer <server.api_token>``; when no
token is configured (allowed only on a loopback bind) those endpoints refuse everyone, so a page
in a local browser cannot change anything behind the user's back. The token comparison is
constant-time. Routers holding such endpoints use :class:`TokenFirstRoute`, which checks the
token of a POST/PUT/PATCH/DELETE before its body is read, so an unauthenticated client gets 401
whatever it sends (never a validation error that describes the body). The OpenAPI document
declares the token as an HTTP bearer scheme on those operations (:data:`bearer_scheme`), so
Swagger UI's Authorize button works.
"""

from __future__ import annotations

import hmac
import json
from collections.abc import Callable, Coroutine
from typing import Annotated, Any

from fastapi import HTTPException, Request, Response, Security
from fastapi.routing import APIRoute
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.errors import Unauthorized

__all__ = [
    "STATE_CHANGING_METHODS",
    "AuthDep",
    "BodySizeLimit",
    "TokenFirstRoute",
    "bearer_scheme",
    "check_token",
    "require_token",
]

STATE_CHANGING_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})


def check_token(request: Request) -> None:
    """Unauthorized (401) unless ``request`` carries the configured bearer token."""
    expected = request.app.state.settings.server.token
    if expected is None:
        raise Unauthorized(
            "state-changing endpoints are disabled: no API token configured (set RIG_API_TOKEN)"
        )
    header = request.headers.get("authorization", "")
    scheme, _, token = header.partition(" ")
    if scheme.lower() != "bearer" or not token:
        raise Unauthorized("missing bearer token (Authorization: Bearer <token>)")
    if not hmac.compare_digest(token.strip().encode(), expected.encode()):
        raise Unauthorized("invalid bearer token")


#: The OpenAPI document's security scheme (``bearer``): Swagger UI's Authorize button sends the
#: token it is given on the operations that need it. It never refuses by itself
#: (``auto_error=False``): :func:`check_token` decides, with the project's 401 details.
bearer_scheme = HTTPBearer(
    auto_error=False,
    scheme_name="bearer",
    description="the service's API token (server.api_token, RIG_API_TOKEN; `rig serve --demo` makes one)",
)


async def require_token(
    request: Request, _credentials: Annotated[HTTPAuthorizationCredentials | None, Security(bearer_scheme)]
) -> None:
    """FastAPI dependency: 401 unless the request carries the configured bearer token."""
    check_token(request)


AuthDep = Annotated[None, Security(require_token)]


class TokenFirstRoute(APIRoute):
    """An APIRoute whose state-changing methods check the bearer token before anything else
    (FastAPI parses and validates the body before it runs dependencies such as :data:`AuthDep`)."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()
        if not (self.methods or set()) & STATE_CHANGING_METHODS:
            return handler

        async def token_first(request: Request) -> Response:
            check_token(request)
            return await handler(request)

        return token_first


class _TooLarge(HTTPException):
    """Raised from inside the body read: FastAPI passes HTTPExceptions through to its handler."""


class BodySizeLimit:
    """ASGI middleware: 413 JSON ``{"detail": ...}`` for request bodies over ``max_bytes``,
    judged by Content-Length up front and by counting a streamed (chunked) body."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    await self._reject(send, 400, "invalid Content-Length header")
                    return
                if declared > self.max_bytes:
                    await self._reject(send, 413, self._message())
                    return
        received = 0
        started = False

        async def counting_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    raise _TooLarge(413, f"request body larger than {self.max_bytes} bytes")
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counting_receive, tracking_send)
        except _TooLarge:
            if not started:
                await self._reject(send, 413, self._message())

    def _message(self) -> str:
        return f"request body larger than {self.max_bytes} bytes"

    @staticmethod
    async def _reject(send: Send, status: int, detail: str) -> None:
        body = json.dumps({"detail": detail}).encode()
        await send(
            {
                "type": "http.response.start",
                "status": status,
                "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})
