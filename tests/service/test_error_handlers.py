"""service.error_handlers: every project exception a route raises becomes its status code and a
JSON ``{"detail": ...}``, through the app ``create_app(settings)`` builds (its middleware and
handlers) under a real uvicorn server, for a tiny route that raises and for real routes."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi import FastAPI

import calibration.errors
import rig.errors
import service.errors
from calibration.errors import CalibrationFileError, ModelError
from service.errors import ApiError, StereoParamsRefused
from service.settings import load_settings
from tests.helpers.service import LiveServer

#: Every exported exception class → the status the API answers it with.
EXPECTED: dict[str, int] = {
    # service
    "ServiceError": 500,
    "SettingsError": 500,
    "ApiError": 500,
    "NotFound": 404,
    "RecordingNotFound": 404,
    "UnknownCamera": 404,
    "UnknownPair": 404,
    "NoPanorama": 404,
    "RecordingNameError": 422,
    "RecordingConflict": 409,
    "RecordingStorageError": 500,
    "ConfidenceOff": 409,
    "ConfigChanged": 412,
    "StereoParamsRefused": 422,
    "NotReady": 503,
    "TooManyStreams": 503,
    "Unauthorized": 401,
    # rig
    "RigError": 500,
    "ConfigError": 422,
    "FaultNotSupported": 409,
    "CameraUnavailable": 500,
    "CameraFormatError": 500,
    "CaptureTimeout": 500,
    "RecordingError": 500,
    "DiskFullError": 507,
    "UsbError": 500,
    "OutputError": 500,  # rig process only; the service writes no output directories
    "ClusterError": 500,  # rig process only
    "LutError": 500,
    "PipelineError": 500,
    "SimulationError": 500,
    "EvaluationError": 500,
    "RectificationError": 500,
    "CorruptFrameError": 500,
    "ResourceExhausted": 500,
    "EndOfStream": 500,
    # calibration
    "CalibrationError": 500,
    "ModelError": 500,
    "CalibrationFileError": 500,
    "CalibrationFailed": 500,
}
MODULES = (service.errors, rig.errors, calibration.errors)
#: 5xx that are no fault of the server's: logging each would let clients fill the log.
UNLOGGED = {"TooManyStreams"}


def exported_errors() -> dict[str, type[Exception]]:
    out = {}
    for module in MODULES:
        for name in module.__all__:
            obj = getattr(module, name)
            if isinstance(obj, type) and issubclass(obj, Exception):
                out[name] = obj
    return out


ERRORS = exported_errors()


def make(cls: type[Exception]) -> tuple[Exception, Any]:
    """An instance of ``cls`` and the ``detail`` it must come back with."""
    if cls is ApiError:
        return ApiError(502, "upstream said no", "/x"), "upstream said no"
    if cls is CalibrationFileError:
        err = CalibrationFileError(Path("/etc/rig/rig.yaml"), "must be a number", "cam0.fx")
        return err, "/etc/rig/rig.yaml: field 'cam0.fx': must be a number"
    if cls is ModelError:
        return ModelError("unknown model 'fisheye9'", "model"), "unknown model 'fisheye9'"
    if cls is StereoParamsRefused:
        fields = [{"loc": ["body", "stereo", "num_disparities"], "msg": "must be positive"}]
        return StereoParamsRefused(fields), fields
    message = f"{cls.__name__} happened: 'left' camera"
    return cls(message), message


@pytest.fixture(scope="module")
def raising_app() -> Iterator[tuple[FastAPI, httpx.Client]]:
    # No lifespan: the runtime is never built (none is needed to raise). No token, whatever
    # RIG_API_TOKEN says.
    live = LiveServer(load_settings(None, {"server": {"api_token": None}}), lifespan="off")
    app = live.app
    pending: list[Exception] = []

    @app.get("/test/raise")
    def raise_pending() -> None:
        raise pending.pop()

    app.state.pending = pending
    live.start()
    # A fresh connection per request: after an unexpected exception uvicorn closes the one it used.
    limits = httpx.Limits(max_keepalive_connections=0)
    with httpx.Client(base_url=live.base_url, timeout=10, limits=limits) as client:
        yield app, client
    live.stop()


def test_every_exported_exception_has_an_expected_status() -> None:
    assert set(ERRORS) == set(EXPECTED)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_each_project_exception_maps_to_its_status_and_detail(
    name: str, raising_app: tuple[FastAPI, httpx.Client], caplog: pytest.LogCaptureFixture
) -> None:
    app, client = raising_app
    err, detail = make(ERRORS[name])
    app.state.pending.append(err)
    with caplog.at_level(logging.ERROR, logger="service.app"):
        r = client.get("/test/raise")
    assert r.status_code == EXPECTED[name], r.text
    assert r.headers["content-type"] == "application/json"
    assert r.json() == {"detail": detail}
    logged = [rec for rec in caplog.records if rec.name == "service.app"]
    # Server faults are logged; client mistakes and load (streams at their limit) are not.
    assert bool(logged) == (r.status_code >= 500 and name not in UNLOGGED)
    assert r.headers.get("WWW-Authenticate") == ("Bearer" if r.status_code == 401 else None)


def test_a_bug_is_500_with_only_its_type(raising_app: tuple[FastAPI, httpx.Client]) -> None:
    app, client = raising_app
    app.state.pending.append(ZeroDivisionError("secret internals"))
    r = client.get("/test/raise")
    assert r.status_code == 500 and r.json() == {"detail": "internal error: ZeroDivisionError"}


def test_real_routes_raise_through_the_same_mapping(raising_app: tuple[FastAPI, httpx.Client]) -> None:
    _, client = raising_app
    r = client.get("/dashboard/nope.js")
    assert r.status_code == 404 and r.json() == {"detail": "no dashboard asset 'nope.js'"}
    for path in ("/depth", "/frames/left", "/calibration"):  # no runtime yet: NotReady
        r = client.get(path)
        assert r.status_code == 503 and r.json() == {"detail": "the service is starting"}, path
    r = client.get("/no/such/path")
    assert r.status_code == 404 and r.json() == {"detail": "Not Found"}
    r = client.delete("/depth")
    assert r.status_code == 405 and r.headers["Allow"] == "GET, HEAD"
    r = client.patch("/config", json={"stereo": {}})  # no token configured: nobody may change state
    assert r.status_code == 401 and r.headers["WWW-Authenticate"] == "Bearer"
    assert r.json() == {
        "detail": "state-changing endpoints are disabled: no API token configured (set RIG_API_TOKEN)"
    }
