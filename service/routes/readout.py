"""Reading metres off the colour depth: ``/depth/colorbar`` (the colour scale of
``/depth/colorized`` and ``/stream.mjpg``, with its ticks in metres) and ``/depth/at`` (range, depth,
disparity and confidence at one pixel of the latest frame). The dashboard's colour bar and hover
read-out use them; each answer costs a few values, whatever the image size."""

from __future__ import annotations

import math
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, Response
from pydantic import BaseModel, Field

from rig.colormap import DepthColors, metres_label
from service.deps import ResultDep, SettingsDep, frame_headers
from service.schemas import ErrorModel

__all__ = ["ColorScaleModel", "ColorTick", "PixelReadout", "router"]

router = APIRouter(tags=["depth"])


class ColorTick(BaseModel):
    metres: float
    position: float = Field(description="0 at near_m, 1 at far_m")
    label: str


class ColorScaleModel(BaseModel):
    near_m: float = Field(description="this distance and nearer: the first colour (turbo's dark red)")
    far_m: float = Field(description="this distance and farther: the last colour (turbo's dark blue)")
    scale: str = Field(description="how distance maps to position between near_m and far_m")
    palette: list[str] = Field(description="256 colours '#rrggbb' from near_m to far_m, evenly on the scale")
    ticks: list[ColorTick]
    invalid: str = Field(description="the colour of pixels with no depth")


class PixelReadout(BaseModel):
    seq: int
    u: int = Field(description="column of the left rectified view")
    v: int = Field(description="row")
    range_m: float | None = Field(description="metres along the pixel's ray; null = no depth there")
    depth_m: float | None = Field(
        description="as /depth: z for the pinhole pair, the range for the lat-lon pair"
    )
    disparity_px: float | None
    confidence: float | None = Field(description="in [0, 1]; null while stereo.confidence is off")


def _value(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


@router.get("/depth/colorbar", response_model=ColorScaleModel, summary="The colour scale of colour depth")
def get_colorbar(settings: SettingsDep) -> ColorScaleModel:
    colors = DepthColors(*settings.server.color_range_m)
    return ColorScaleModel(
        near_m=colors.near_m,
        far_m=colors.far_m,
        scale="log",
        palette=[f"#{r:02x}{g:02x}{b:02x}" for r, g, b in colors.palette().tolist()],
        ticks=[
            ColorTick(metres=m, position=float(colors.position(m)), label=metres_label(m))
            for m in colors.ticks()
        ],
        invalid="#000000",
    )


@router.get(
    "/depth/at",
    response_model=PixelReadout,
    summary="Range, depth, disparity and confidence at one pixel of the latest frame",
    responses={
        422: {"model": ErrorModel, "description": "a pixel outside the rectified view, or no integer"},
        503: {"model": ErrorModel, "description": "no depth frame yet"},
    },
)
def get_depth_at(
    result: ResultDep,
    response: Response,
    u: Annotated[int, Query(ge=0, description="column of the left rectified view")],
    v: Annotated[int, Query(ge=0, description="row")],
) -> PixelReadout:
    frame = result.frame
    height, width = frame.range.shape
    if u >= width or v >= height:
        raise HTTPException(422, f"pixel ({u}, {v}) is outside the {width}x{height} rectified view")
    confidence = frame.confidence
    response.headers.update(frame_headers(result))
    return PixelReadout(
        seq=result.seq,
        u=u,
        v=v,
        range_m=_value(frame.range[v, u]),
        depth_m=_value(frame.depth[v, u]),
        disparity_px=_value(frame.disparity[v, u]),
        confidence=None if confidence is None else float(confidence[v, u]),
    )
