"""Depth, range, disparity, confidence, colourised depth and point cloud of the latest frame."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from fastapi import APIRouter, Query, Response

from service.deps import (
    ResultDep,
    RuntimeDep,
    SettingsDep,
    binary_response_doc,
    cached_body,
    frame_body,
    frame_headers,
)
from service.encoders import (
    CONFIDENCE_PNG_SCALE,
    DISPARITY_PNG_SCALE,
    colorize_depth,
    depth_png,
    encode_jpeg,
    npy_bytes,
    pcd_bytes,
    ply_bytes,
)
from service.routes.ring import first_pair, pair_frame
from service.runtime import Runtime
from service.settings import Settings
from service.store import PublishedResult

__all__ = ["ArrayBody", "ArrayEndpoint", "ArrayFormat", "array_body", "colorized_body", "router"]

router = APIRouter(tags=["depth"])

NPY = "application/x-npy"
PLY = "application/x-ply"
PCD = "application/x-pcd"
CloudFormat = Literal["ply", "pcd"]
ArrayFormat = Literal["png", "npy"]
ArrayEndpoint = Literal["depth", "range", "disparity", "confidence", "pinhole_depth"]
_SCALE_HEADERS: dict[str, str] = {
    "depth": "X-Depth-Scale",
    "pinhole_depth": "X-Depth-Scale",
    "range": "X-Range-Scale",
    "disparity": "X-Disparity-Scale",
    "confidence": "X-Confidence-Scale",
}
_PNG_SCALES: dict[str, float] = {"disparity": DISPARITY_PNG_SCALE, "confidence": CONFIDENCE_PNG_SCALE}


@dataclass(frozen=True)
class ArrayBody:
    """How ``GET /depth``, ``/range``, ``/disparity`` or ``/confidence`` answers in one
    ``format``: the runtime's frame body (``Runtime.frame_bodies`` key), its media type and the
    scale header. Shared by the routes and :mod:`service.fast_path`, so both give the same
    response."""

    key: str
    media_type: str
    headers: dict[str, str]


def array_body(endpoint: ArrayEndpoint, format: ArrayFormat, depth_scale_m: float) -> ArrayBody:
    """The :class:`ArrayBody` of ``endpoint`` in ``format`` (PNG depth and range in units of
    ``depth_scale_m``)."""
    if format == "npy":
        scale = "1"
    elif endpoint in ("depth", "range", "pinhole_depth"):
        scale = f"{depth_scale_m:g}"
    else:
        scale = f"{_PNG_SCALES[endpoint]:g}"
    media_type = NPY if format == "npy" else "image/png"
    return ArrayBody(f"{endpoint}_{format}", media_type, {_SCALE_HEADERS[endpoint]: scale})


async def _array_response(
    endpoint: ArrayEndpoint,
    format: ArrayFormat,
    result: PublishedResult,
    runtime: Runtime,
    settings: Settings,
) -> Response:
    spec = array_body(endpoint, format, settings.server.depth_scale_m)
    body = await frame_body(runtime, result, spec.key)
    return Response(body, media_type=spec.media_type, headers=frame_headers(result, **spec.headers))


@router.get(
    "/depth",
    response_class=Response,
    summary="Latest depth map",
    responses=binary_response_doc(
        "png: uint16 in units of X-Depth-Scale metres (1 mm default), 0 = invalid; npy: float32 metres, "
        "NaN = invalid. The pinhole pair (vpc.projection pinhole): z in the left VPC frame. The lat-lon "
        "pair (vpc.projection latlon): the range along each pixel's ray, as /range (its rays reach past "
        "90° off the forward axis, where z is no depth).",
        "image/png",
        NPY,
        scale_header="X-Depth-Scale",
    ),
)
async def get_depth(
    result: ResultDep,
    runtime: RuntimeDep,
    settings: SettingsDep,
    format: Annotated[ArrayFormat, Query(description="png (16-bit) or npy (float32 m)")] = "png",
) -> Response:
    return await _array_response("depth", format, result, runtime, settings)


@router.get(
    "/range",
    response_class=Response,
    summary="Latest range map (metres along each pixel's ray)",
    responses=binary_response_doc(
        "png: uint16 in units of X-Range-Scale metres (server.depth_scale_m, 1 mm default), 0 = invalid; "
        "npy: float32 metres, NaN = invalid. The distance from the left rectified view's centre along "
        "each pixel's ray, for either projection; aligned with /depth and /frames/left?view=rectified.",
        "image/png",
        NPY,
        scale_header="X-Range-Scale",
        not_found="?pair= names no pair of the rig (the detail lists them)",
    ),
)
async def get_range(
    result: ResultDep,
    runtime: RuntimeDep,
    settings: SettingsDep,
    format: Annotated[ArrayFormat, Query(description="png (16-bit) or npy (float32 m)")] = "png",
    pair: Annotated[
        str | None, Query(description="a rig of N cameras: the stereo pair A-B (default: the first)")
    ] = None,
) -> Response:
    if pair is None or pair == first_pair(runtime):
        return await _array_response("range", format, result, runtime, settings)
    frame = pair_frame(runtime, result, pair)
    spec = array_body("range", format, settings.server.depth_scale_m)
    scale, level = settings.server.depth_scale_m, settings.server.png_compression

    def produce() -> bytes:
        return npy_bytes(frame.range) if format == "npy" else depth_png(frame.range, scale, level)

    body = await cached_body(result, f"{spec.key}:{pair}", produce)
    return Response(body, media_type=spec.media_type, headers=frame_headers(result, **spec.headers))


@router.get(
    "/depth/pinhole",
    response_class=Response,
    summary="Latest depth on a pinhole image (what ROS depth tools read)",
    responses=binary_response_doc(
        "png: uint16 in units of X-Depth-Scale metres, 0 = invalid; npy: float32 metres, NaN = invalid. "
        "z on a distortion-free pinhole in the left rectified frame (settings pinhole_depth: size, "
        "field of view; its CameraInfo: /camera_info/pinhole_depth, plumb_bob, zero D), cut from the "
        "range of whichever rectified pair is in effect: depth_image_proc, Nav2 and RViz build the "
        "right cloud from it, where they would misread the lat-lon pair's /depth.",
        "image/png",
        NPY,
        scale_header="X-Depth-Scale",
    ),
)
async def get_pinhole_depth(
    result: ResultDep,
    runtime: RuntimeDep,
    settings: SettingsDep,
    format: Annotated[ArrayFormat, Query(description="png (16-bit) or npy (float32 m)")] = "png",
) -> Response:
    return await _array_response("pinhole_depth", format, result, runtime, settings)


@router.get(
    "/disparity",
    response_class=Response,
    summary="Latest disparity map",
    responses=binary_response_doc(
        "png: uint16 in 1/16 px (X-Disparity-Scale), 0 = invalid; npy: float32 px, NaN = invalid.",
        "image/png",
        NPY,
    ),
)
async def get_disparity(
    result: ResultDep,
    runtime: RuntimeDep,
    settings: SettingsDep,
    format: Annotated[ArrayFormat, Query(description="png (16-bit, 1/16 px) or npy (float32 px)")] = "png",
) -> Response:
    return await _array_response("disparity", format, result, runtime, settings)


@router.get(
    "/confidence",
    response_class=Response,
    summary="Latest confidence map (how far each depth pixel can be trusted)",
    responses={
        **binary_response_doc(
            "png: uint8 in 1/255 (X-Confidence-Scale), 255 = 1; npy: float32 in [0, 1]. "
            "exp(−σ_d / stereo.confidence_sigma) of the disparity's predicted standard deviation; "
            "0 where depth is invalid. Aligned with /depth.",
            "image/png",
            NPY,
        ),
        409: {
            "description": "stereo.confidence is off",
            "content": {"application/json": {"schema": {"type": "object"}}},
        },
    },
)
async def get_confidence(
    result: ResultDep,
    runtime: RuntimeDep,
    settings: SettingsDep,
    format: Annotated[ArrayFormat, Query(description="png (8-bit) or npy (float32)")] = "png",
) -> Response:
    result.confidence()  # 409 with the fix when this frame has none
    return await _array_response("confidence", format, result, runtime, settings)


async def colorized_body(runtime: Runtime, result: PublishedResult) -> bytes:
    """The colour-mapped depth JPEG of ``result`` (shared by /depth/colorized and the stream)."""
    near, far = runtime.settings.server.color_range_m
    quality = runtime.settings.server.jpeg_quality
    depth = result.frame.depth
    return await cached_body(
        result, "colorized", lambda: encode_jpeg(colorize_depth(depth, near, far), quality)
    )


@router.get(
    "/depth/colorized",
    response_class=Response,
    summary="Latest depth as a colour-mapped JPEG (the dashboard's and the stream's image)",
    responses=binary_response_doc(
        "turbo on log depth (the lat-lon pair: range) between server.color_range_m, near dark red, far "
        "dark blue (GET /depth/colorbar: the scale and its ticks in metres); black = invalid",
        "image/jpeg",
    ),
)
async def get_depth_colorized(runtime: RuntimeDep, result: ResultDep) -> Response:
    body = await colorized_body(runtime, result)
    return Response(body, media_type="image/jpeg", headers=frame_headers(result))


@router.get(
    "/pointcloud",
    response_class=Response,
    summary="Latest point cloud (binary PLY or PCD, rig frame, metres; a rig of N cameras: fused)",
    responses=binary_response_doc(
        "ply: binary little-endian PLY, x y z float32 (rig frame, m) and red green blue uchar; "
        "pcd: binary PCD 0.7 (PCL), x y z float32 and PCL's packed rgb",
        PLY,
        PCD,
        not_found="?pair= names no pair of the rig (the detail lists them)",
    ),
)
async def get_pointcloud(
    runtime: RuntimeDep,
    result: ResultDep,
    stride: Annotated[int, Query(ge=1, le=64, description="use every stride-th pixel of each axis")] = 1,
    format: Annotated[CloudFormat, Query(description="ply or pcd")] = "ply",
    pair: Annotated[
        str | None,
        Query(description="a rig of N cameras: one stereo pair's cloud, A-B (default: the fused cloud)"),
    ] = None,
) -> Response:
    encode = ply_bytes if format == "ply" else pcd_bytes
    ring = result.ring

    def produce() -> bytes:
        if ring is not None and pair is None:  # the fused cloud: the panorama's points
            return encode(*ring.pipeline.point_cloud(ring.rig_frame(), stride))
        if pair is None or pair == first_pair(runtime):
            points, colors = runtime.pipeline.point_cloud(
                result.frame, stride, image=result.rect_image("left")
            )
            return encode(points, colors)
        assert runtime.ring is not None  # pair_frame below refused any other name
        return encode(*runtime.ring.pipeline(pair).point_cloud(frame, stride))

    if pair is not None:
        frame = pair_frame(runtime, result, pair)  # 404 naming the pairs for an unknown one
    key = f"pointcloud:{stride}" if format == "ply" else f"pointcloud:{format}:{stride}"
    key += "" if pair is None else f":{pair}"
    body = await cached_body(result, key, produce)
    headers = frame_headers(
        result, **{"Content-Disposition": f'inline; filename="depth_{result.seq:06d}.{format}"'}
    )
    return Response(body, media_type=PLY if format == "ply" else PCD, headers=headers)
