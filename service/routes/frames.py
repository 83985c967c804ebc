"""Camera frames of the latest processed pair: the raw fisheye frames and the VPC images."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Path, Query, Response

from service.deps import (
    ResultDep,
    SettingsDep,
    binary_response_doc,
    cached_body,
    check_camera,
    frame_headers,
)
from service.encoders import encode_jpeg

__all__ = ["router"]

router = APIRouter(tags=["frames"])

_DOC = binary_response_doc(
    "JPEG. raw: the fisheye frame as the camera delivered it (MJPEG bytes unchanged; other formats "
    "encoded once); rectified (also vpc, its first name): the rectified image.",
    "image/jpeg",
)
_DOC[404] = {"description": "unknown camera", "content": {"application/json": {"schema": {"type": "object"}}}}


@router.get("/frames/{camera}", response_class=Response, summary="Latest frame of one camera", responses=_DOC)
async def get_frame(
    result: ResultDep,
    settings: SettingsDep,
    camera: Annotated[str, Path(description="left or right")],
    view: Annotated[
        Literal["raw", "rectified", "vpc"],
        Query(description="raw fisheye frame or rectified image (vpc: the rectified image's first name)"),
    ] = "rectified",
) -> Response:
    check_camera(camera)
    quality = settings.server.jpeg_quality
    headers = frame_headers(result, **{"X-Camera": camera, "X-View": view})
    if view != "raw":
        # Colour rectified images are made on request (the worker works on luma only).
        body = await cached_body(
            result, f"rectified:{camera}", lambda: encode_jpeg(result.rect_image(camera), quality)
        )
        return Response(body, media_type="image/jpeg", headers=headers)
    raw = result.raw_frame(camera)
    # X-Frame-Seq/X-Timestamp-Ns stay the pair's (as on every endpoint); this camera's own:
    headers["X-Camera-Seq"] = str(raw.seq)
    headers["X-Camera-Timestamp-Ns"] = str(raw.ts_ns)
    if raw.format == "jpeg" and raw.raw is not None:
        return Response(raw.raw, media_type="image/jpeg", headers=headers)
    body = await cached_body(result, f"raw:{camera}", lambda: encode_jpeg(raw.image, quality))
    return Response(body, media_type="image/jpeg", headers=headers)
