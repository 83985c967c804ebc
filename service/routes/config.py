"""``/config``: the effective configuration (GET) and live stereo parameter changes (PATCH)."""

from __future__ import annotations

import cv2
from fastapi import APIRouter, HTTPException
from fastapi.encoders import jsonable_encoder
from pydantic import ValidationError

from rig.errors import ConfigError
from rig.stereo import StereoParams
from service.deps import RuntimeDep
from service.runtime import Runtime
from service.schemas import BODY_ERRORS, ConfigModel, ConfigPatch, ServerPublicModel
from service.security import AuthDep

__all__ = ["config_model", "router"]

router = APIRouter(tags=["config"])


def config_model(runtime: Runtime) -> ConfigModel:
    s = runtime.settings
    server = s.server
    return ConfigModel(
        stereo=runtime.pipeline.stereo,
        vpc=runtime.pipeline.vpc_config,
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


@router.get("/config", response_model=ConfigModel, summary="Effective configuration (no secrets)")
def get_config(runtime: RuntimeDep) -> ConfigModel:
    return config_model(runtime)


@router.patch(
    "/config",
    response_model=ConfigModel,
    summary="Change stereo parameters (takes effect at the next frame)",
    responses=BODY_ERRORS,
)
def patch_config(patch: ConfigPatch, runtime: RuntimeDep, _auth: AuthDep) -> ConfigModel:
    # null = keep the current value (the schema allows null for every field).
    changes = {k: v for k, v in patch.stereo.model_dump(exclude_unset=True).items() if v is not None}
    current = runtime.pipeline.stereo
    try:
        params = StereoParams.model_validate({**current.model_dump(), **changes})
        runtime.pipeline.update_stereo(params)
    except ValidationError as err:
        detail = jsonable_encoder(err.errors(include_url=False, include_context=False))
        for item in detail:
            item["loc"] = ["body", "stereo", *item.get("loc", [])]
        raise HTTPException(422, detail) from err
    except ConfigError as err:
        raise HTTPException(422, str(err)) from err
    except (ValueError, OverflowError, cv2.error) as err:  # valid for pydantic, refused by OpenCV
        raise HTTPException(422, f"stereo parameters refused by the matcher: {err}") from err
    return config_model(runtime)
