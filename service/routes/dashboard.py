"""``/``: the dashboard page and its assets (plain JS modules, a style sheet), served from the
package (no build step, nothing fetched from elsewhere: it works offline)."""

from __future__ import annotations

from functools import cache
from importlib import resources

from fastapi import APIRouter, Response
from fastapi.responses import HTMLResponse

from service.errors import NotFound

__all__ = ["router"]

router = APIRouter(tags=["dashboard"])

_JS = "text/javascript; charset=utf-8"
_ASSETS = {
    "app.js": _JS,
    "cloud.js": _JS,
    "controls.js": _JS,
    "readout.js": _JS,
    "style.css": "text/css; charset=utf-8",
}


@cache
def _read(name: str) -> bytes:
    return resources.files("service").joinpath("dashboard", name).read_bytes()


@router.get("/", response_class=HTMLResponse, summary="Dashboard page")
def dashboard() -> HTMLResponse:
    return HTMLResponse(_read("index.html"), headers={"Cache-Control": "no-cache"})


@router.get("/favicon.ico", include_in_schema=False)
def favicon() -> Response:
    return Response(status_code=204)


@router.get("/dashboard/{name}", include_in_schema=False)
def dashboard_asset(name: str) -> Response:
    if name not in _ASSETS:
        raise NotFound(f"no dashboard asset {name!r}")
    return Response(_read(name), media_type=_ASSETS[name], headers={"Cache-Control": "no-cache"})
