"""schemathesis against the running service's own ``/openapi.json``: every operation, generated
requests (valid and invalid, with the bearer token so state-changing operations really run),
bounded examples. Every response must be a non-5xx answer that conforms to the schema (status
code, content type, headers, body), valid data must be accepted and invalid data rejected.

The server is a dedicated one (recordings and faults that schemathesis creates stay with it);
``/stream.mjpg`` is asked for a few parts only (without ``max_frames`` it never ends).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis import GenerationMode
from schemathesis.checks import positive_data_acceptance

from service.app import create_app
from service.client import RigClient
from service.errors import ApiError
from tests.helpers.command import clean_env, start_serve
from tests.helpers.service import AUTH, TOKEN, LiveServer, StartApp, service_settings, write_serve_config
from tests.helpers.waiting import wait_for

pytestmark = [pytest.mark.timeout(900)]

EXAMPLES_PER_OPERATION = 40
#: rig.stereo.StereoParams' cross-field rules (16-bit path costs among them), the pipeline's
#: width limit, OpenCV's own refusals, the trial on the newest frame and the memory budget.
CROSS_FIELD_RULES = (
    "full_dp conflicts with sgbm_mode",
    "must be >= 5 for block matching",
    "must be larger than P1",
    "overflows SGBM's 16-bit path costs",
    "must be below the rectified view's width",
    "refused by the matcher",
    "stereo parameters refused: on the newest frame",
    "MiB this machine has left",
)


@pytest.fixture(scope="module")
def api_server(
    jpeg_recording: Path, lut_cache: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[LiveServer]:
    live = LiveServer(service_settings(jpeg_recording, tmp_path_factory.mktemp("schema"), lut_cache)).start()
    live.wait_ready()
    yield live
    live.stop()


def openapi_document() -> dict[str, Any]:
    """The document the service serves, from the app object alone (no runtime is started:
    schemathesis needs it at collection time; its lazy fixture loader fails on pytest 9)."""
    unused = Path("/nonexistent")
    return create_app(service_settings(unused / "recording", unused, unused)).openapi()


schema = schemathesis.openapi.from_dict(openapi_document())


@pytest.mark.slow
@schema.parametrize()
@settings(
    max_examples=EXAMPLES_PER_OPERATION,
    deadline=None,
    suppress_health_check=[
        HealthCheck.too_slow,
        HealthCheck.filter_too_much,
        HealthCheck.function_scoped_fixture,
    ],
)
def test_every_operation_conforms_to_its_schema(case: Any, api_server: LiveServer) -> None:
    if case.path == "/stream.mjpg" and isinstance(case.query, dict):
        frames = case.query.get("max_frames")
        if not isinstance(frames, int) or isinstance(frames, bool) or frames > 3:
            case.query["max_frames"] = 2  # a finite stream (the body is read to the end)
    elif case.path == "/stream.mjpg":
        case.query = {"max_frames": 2}
    if (case.method.upper(), case.path) == ("GET", "/depth/at"):
        # The rectified view's size is the pair in effect's, not the schema's: a pixel beyond it
        # is the documented 422 naming the size; any other refusal of schema-valid data fails.
        response = case.call_and_validate(
            base_url=api_server.base_url, headers=AUTH, timeout=30, excluded_checks=[positive_data_acceptance]
        )
        positive = case.meta is not None and case.meta.generation.mode == GenerationMode.POSITIVE
        if positive and response.status_code != 200:
            detail = str(response.json()["detail"])
            assert response.status_code == 422 and "is outside the 320x240 rectified view" in detail, detail
        return
    if (case.method.upper(), case.path) != ("PATCH", "/config"):
        case.call_and_validate(base_url=api_server.base_url, headers=AUTH, timeout=30)
        return
    # A PATCH is merged into the current parameters; the merged set must satisfy StereoParams'
    # cross-field rules and the VPC/matcher limits, which depend on the current state and so
    # cannot be in the schema. Such a refusal is the documented 422 naming the rule, or 412 for an
    # If-Match that is not the current revision; any other refusal of schema-valid data still fails.
    response = case.call_and_validate(
        base_url=api_server.base_url, headers=AUTH, timeout=30, excluded_checks=[positive_data_acceptance]
    )
    positive = case.meta is not None and case.meta.generation.mode == GenerationMode.POSITIVE
    if_match = {k.lower(): v for k, v in (case.headers or {}).items()}.get("if-match")
    if positive and response.status_code == 412:  # a generated If-Match: a revision, or not
        assert if_match is not None and if_match.strip() != "*", if_match
        return
    if positive and response.status_code != 200:
        detail = str(response.json()["detail"])
        assert response.status_code == 422 and any(rule in detail for rule in CROSS_FIELD_RULES), detail


def test_schemathesis_saw_every_operation(api_server: LiveServer) -> None:
    """The running server serves exactly the document the cases were generated from, and the
    parametrized test covers every operation in it."""
    spec = httpx.get(api_server.base_url + "/openapi.json").json()
    assert spec == openapi_document()
    results: list[Any] = list(schema.get_all_operations())  # Ok(operation) or Err(invalid schema)
    generated = {(r.ok().method.upper(), r.ok().path) for r in results}
    operations = {(m.upper(), p) for p, ops in spec["paths"].items() for m in ops}
    assert generated == operations
    assert ("PATCH", "/config") in operations and ("POST", "/cameras/{camera}/faults") in operations
    assert ("POST", "/recordings") in operations and ("GET", "/stream.mjpg") in operations
    assert len(operations) >= 18


def test_a_patch_opencv_refuses_only_when_matching_is_refused_up_front(
    start_app: StartApp,
) -> None:
    """Found by the generated PATCHes: full SGBM with 304 disparities from 10 and a 19 px window
    passes every static check on a 320 px VPC, then OpenCV refused every frame in the worker."""
    live = start_app()
    with live.rig_client(TOKEN) as client:
        before = client.config().stereo
        errors = client.health().worker.errors
        with pytest.raises(ApiError) as refused:
            client.patch_config(
                sgbm_mode="sgbm", disparity_range=304, min_disparity=10, correlation_window_size=19
            )
        assert refused.value.status == 422 and "refused by the matcher" in str(refused.value.detail)
        assert client.config().stereo == before
        seq = client.depth().seq
        wait_for(lambda: client.depth().seq > seq + 2, 10, "depth with the unchanged parameters")
        assert client.health().worker.errors == errors


@pytest.mark.slow
def test_a_patch_that_would_crash_opencv_is_refused_and_the_service_lives(
    jpeg_recording: Path, lut_cache: Path, tmp_path: Path
) -> None:
    """Found by the generated PATCHes: uniqueness_ratio 100 with SGBM_3WAY (the default mode)
    makes OpenCV divide by zero (SIGFPE): the service process died. A subprocess here, so a
    regression fails this test instead of killing the test run."""
    cfg = write_serve_config(tmp_path / "serve.yaml", jpeg_recording, tmp_path, lut_cache, port=0)
    served = start_serve(["--config", str(cfg), "--log-level", "warning"], clean_env(tmp_path))
    try:
        with RigClient(served.url, token=TOKEN, timeout=30) as client:

            def ready() -> bool:
                try:
                    return client.ready()
                except ApiError:  # not listening yet: the URL is printed once the port is bound
                    return False

            wait_for(ready, 60, "the first depth frame", poll_s=0.2)
            for ratio in (100.0, 99.5):
                with pytest.raises(ApiError) as refused:
                    client.patch_config(uniqueness_ratio=ratio)
                # Refused by the schema bound (uniqueness_ratio < 99.5), the one guard against it.
                detail = str(refused.value.detail)
                assert refused.value.status == 422
                assert "uniqueness_ratio" in detail
            # 99.0 is inside the bound: the matcher runs it; on this scene it gives depth on far
            # less than the parameters in effect, so the trial on the newest frame refuses it.
            with pytest.raises(ApiError) as collapsed:
                client.patch_config(uniqueness_ratio=99.0)
            assert collapsed.value.status == 422
            assert str(collapsed.value.detail).startswith("stereo parameters refused: on the newest frame")
            assert client.patch_config(uniqueness_ratio=20.0).stereo.uniqueness_ratio == 20.0
            seq = client.depth().seq
            wait_for(lambda: client.depth().seq > seq + 2, 15, "depth after the refused PATCH")
            assert served.proc.poll() is None
    finally:
        text = served.stop()
    assert served.proc.returncode == 0 and "Traceback" not in text
