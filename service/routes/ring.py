"""A rig of N cameras: its 360° range panorama (``/panorama``, ``/panorama/info``), and the
choice of one of its stereo pairs that ``/range`` and ``/pointcloud`` take (``?pair=A-B``).

The panorama is fused from the latest set's pairs when a client first asks for it (once per
set, whoever asks; :class:`service.store.RingResult`): the depth worker never waits for it.
"""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Query, Response

from rig.pipeline import DepthFrame
from rig.ring import pair_label
from service.deps import (
    ResultDep,
    RuntimeDep,
    SettingsDep,
    binary_response_doc,
    cached_body,
    frame_headers,
    not_found_doc,
)
from service.encoders import colorize_depth, depth_png, encode_jpeg, npy_bytes
from service.errors import NoPanorama, UnknownPair
from service.runtime import Runtime
from service.store import PublishedResult, RingResult

__all__ = ["first_pair", "pair_frame", "router"]

router = APIRouter(tags=["depth"])

NPY = "application/x-npy"


def first_pair(runtime: Runtime) -> str:
    """The name (``A-B``) of the pair the endpoints serve by default: the rig's first."""
    return runtime.ring.labels[0] if runtime.ring is not None else pair_label(runtime.pipeline.names)


def pair_frame(runtime: Runtime, result: PublishedResult, pair: str) -> DepthFrame:
    """``result``'s depth of pair ``pair``; UnknownPair (404) naming the rig's pairs otherwise."""
    if pair == first_pair(runtime):
        return result.frame
    ring = result.ring
    labels = runtime.ring.labels if runtime.ring is not None else [first_pair(runtime)]
    if ring is None or pair not in ring.pairs:
        raise UnknownPair(f"no pair {pair!r}; the rig's pairs: {', '.join(labels)}")
    return ring.pairs[pair]


def _ring(result: PublishedResult) -> RingResult:
    if result.ring is None:
        raise NoPanorama("a two-camera rig has one pair and no panorama: /range is its range")
    return result.ring


@router.get(
    "/panorama",
    response_class=Response,
    summary="Latest 360° range panorama of a rig of N cameras",
    responses={
        **binary_response_doc(
            "png: uint16 in units of X-Range-Scale metres (server.depth_scale_m), 0 = invalid; npy: "
            "float32 metres, NaN = invalid. The range from the panorama's origin along each pixel's "
            "ray (equirectangular, 360° of azimuth by 180° of elevation; /panorama/info), fused from "
            "the latest set's pairs.",
            "image/png",
            NPY,
            scale_header="X-Range-Scale",
        ),
        **not_found_doc("a two-camera rig (no panorama)"),
    },
)
async def get_panorama(
    result: ResultDep,
    settings: SettingsDep,
    format: Annotated[Literal["png", "npy"], Query(description="png (16-bit) or npy (float32 m)")] = "png",
) -> Response:
    ring = _ring(result)
    scale, level = settings.server.depth_scale_m, settings.server.png_compression

    def produce() -> bytes:
        rng = ring.panorama().range
        return npy_bytes(rng) if format == "npy" else depth_png(rng, scale, level)

    body = await cached_body(result, f"panorama_{format}", produce)
    headers = frame_headers(result, **{"X-Range-Scale": "1" if format == "npy" else f"{scale:g}"})
    return Response(body, media_type=NPY if format == "npy" else "image/png", headers=headers)


@router.get(
    "/panorama/colorized",
    response_class=Response,
    summary="Latest panorama as a colour-mapped JPEG (the dashboard's)",
    responses=binary_response_doc(
        "/depth/colorized's colour scale (GET /depth/colorbar) on the panorama's range; black = no range",
        "image/jpeg",
        not_found="a two-camera rig (no panorama)",
    ),
)
async def get_panorama_colorized(result: ResultDep, settings: SettingsDep) -> Response:
    ring = _ring(result)
    near, far = settings.server.color_range_m
    quality = settings.server.jpeg_quality

    def produce() -> bytes:
        return encode_jpeg(colorize_depth(ring.panorama().range, near, far), quality)

    body = await cached_body(result, "panorama_colorized", produce)
    return Response(body, media_type="image/jpeg", headers=frame_headers(result))


@router.get(
    "/panorama/info",
    summary="The panorama's projection, frame and pairs (panorama.json)",
    responses=not_found_doc("a two-camera rig (no panorama)"),
)
async def get_panorama_info(runtime: RuntimeDep) -> dict[str, object]:
    if runtime.ring is None:
        raise NoPanorama("a two-camera rig has one pair and no panorama")
    return runtime.ring.panorama.as_json(runtime.ring.labels)
