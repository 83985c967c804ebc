"""``/config``: the effective configuration (GET) and live stereo parameter changes (PATCH).

Changes are serialised: each PATCH reads the current parameters, merges its fields, validates
them and swaps them into the pipeline under one lock, so concurrent writers of different fields
all keep their change, and writers of one field end with the last one in the server's order. A
200 means the pipeline holds the change: every pair matched after the answer uses it. Each
change raises the configuration's revision, sent as ``ETag`` by GET and PATCH (the order in
which the server applied the changes). A PATCH with ``If-Match`` applies only to that revision
(412 otherwise), for clients that change a value derived from the one they read.
"""

from __future__ import annotations

from typing import Annotated

import cv2
import numpy as np
from fastapi import APIRouter, Header, Response
from fastapi.encoders import jsonable_encoder
from pydantic import ValidationError

from rig.depth_watch import try_settings
from rig.errors import ConfigError, PipelineError
from rig.in_effect import PairInEffect
from rig.pipeline import DepthPipeline
from rig.stereo import StereoMatcher, StereoParams
from service.deps import RuntimeDep
from service.errors import StereoParamsRefused
from service.routes.calibration import rectified_pair_model
from service.runtime import Runtime, etag
from service.schemas import BODY_ERRORS, ConfigModel, ConfigPatch, ErrorModel, ServerPublicModel
from service.security import AuthDep, TokenFirstRoute

__all__ = ["config_model", "router"]

router = APIRouter(tags=["config"], route_class=TokenFirstRoute)


def config_model(runtime: Runtime, in_effect: PairInEffect) -> ConfigModel:
    s = runtime.settings
    server = s.server
    return ConfigModel(
        revision=in_effect.revision,
        stereo=in_effect.stereo,
        nearest_range_m=in_effect.nearest_range_m,
        rectified=rectified_pair_model(in_effect),
        vpc=in_effect.config,
        server=ServerPublicModel(
            host=server.host,
            port=server.port,
            depth_scale_m=server.depth_scale_m,
            jpeg_quality=server.jpeg_quality,
            stream_fps=server.stream_fps,
            cors_origins=server.cors_origins,
            max_body_bytes=server.max_body_bytes,
            recordings_dir=str(server.recordings_dir),
            api_token_set=server.api_token is not None,
        ),
        cameras=None if s.cameras is None else s.cameras.model_dump(mode="json"),
    )


def dry_run(pipeline: DepthPipeline, params: StereoParams) -> None:
    """Run a matcher with ``params`` once on a blank pair of the rectified size: OpenCV checks some
    limits (window vs. disparity range vs. image width) only when it matches, and a refused
    configuration must be refused here, not fail every frame in the worker. Values that would
    crash OpenCV itself never get here: :class:`StereoParams`' bounds refuse them."""
    cam = pipeline.pair.camera
    blank = np.zeros((cam.height, cam.width), dtype=np.uint8)
    StereoMatcher(params).match(blank, blank)


def _trial(runtime: Runtime, params: StereoParams) -> None:
    """Refuse parameters that break the matcher on the newest frame (rig.depth_watch): inside
    every field's bounds, some combinations give depth on almost nothing, or wrong depth on
    everything (StereoParams refuses those it can tell; this catches what only the scene shows)."""
    result = runtime.store.latest
    if result is None:
        return
    frame = result.frame
    trial = try_settings(runtime.pipeline.in_effect, frame.left_rect, frame.right_rect, params)
    why = trial.collapse()
    if why is not None:
        raise StereoParamsRefused(f"stereo parameters refused: {why}")


@router.get("/config", response_model=ConfigModel, summary="Effective configuration (no secrets)")
def get_config(runtime: RuntimeDep, response: Response) -> ConfigModel:
    in_effect = runtime.pipeline.in_effect  # never waits for a change being applied
    response.headers["ETag"] = etag(in_effect.revision)
    return config_model(runtime, in_effect)


def _merged_params(runtime: Runtime, current: StereoParams, changes: dict[str, object]) -> StereoParams:
    """``current`` with ``changes``, validated and tried on the matcher."""
    try:
        params = StereoParams.model_validate({**current.model_dump(), **changes})
        dry_run(runtime.pipeline, params)
    except ValidationError as err:
        detail = jsonable_encoder(err.errors(include_url=False, include_context=False))
        for item in detail:
            item["loc"] = ["body", "stereo", *item.get("loc", [])]
        raise StereoParamsRefused(detail) from err
    except ConfigError:
        raise  # its own message (422)
    except (ValueError, OverflowError, cv2.error, PipelineError) as err:  # refused by OpenCV
        width = runtime.pipeline.pair.camera.width
        message = " ".join(str(err).split())
        raise StereoParamsRefused(
            f"stereo parameters refused by the matcher (rectified width {width} px): {message}"
        ) from err
    _trial(runtime, params)
    return params


@router.patch(
    "/config",
    response_model=ConfigModel,
    summary="Change stereo parameters (in effect when answered: the next pair matched uses them)",
    responses={**BODY_ERRORS, 412: {"model": ErrorModel, "description": "If-Match names an old revision"}},
)
def patch_config(
    patch: ConfigPatch,
    runtime: RuntimeDep,
    response: Response,
    _auth: AuthDep,
    if_match: Annotated[str | None, Header(description="apply only to this revision (the ETag)")] = None,
) -> ConfigModel:
    # null = keep the current value (the schema allows null for every field).
    changes = {k: v for k, v in patch.stereo.model_dump(exclude_unset=True).items() if v is not None}
    wanted = None
    if if_match is not None and if_match.strip() != "*":
        wanted = [tag.strip().removeprefix("W/") for tag in if_match.split(",")]
    in_effect = runtime.change_stereo(lambda current: _merged_params(runtime, current, changes), wanted)
    response.headers["ETag"] = etag(in_effect.revision)
    return config_model(runtime, in_effect)
