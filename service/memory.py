"""The service's memory budget: the pipeline's parts (:mod:`rig.memory_budget`) and the service's
own, from the settings and the calibrated camera sizes, known before anything is built.

:func:`check_memory` refuses at start-up a configuration whose budget exceeds the memory the
machine has left (one line naming the rectified pair's size and the largest parts) and warns above
:data:`WARN_SHARE` of it. The running service exports the budget (``rig_memory_budget_bytes`` in
``/metrics``); its resident size stays under it (docs/reliability.md, "Memory budget").

The service's parts: frames waiting for the recording writer (``server.recording_queue`` pairs,
raw and gray: 2 bytes per camera pixel), HTTP connections (a request body and uvicorn's 64 KiB
read and write buffers each), streams (a part of at most one byte per rectified pixel and the socket's
send buffer each), and the interpreter with its libraries loaded (:data:`BASE_BYTES`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

from calibration.rig import Rig
from rig.memory_budget import MIB, MemoryEstimate, available_memory, pipeline_parts, ring_parts
from rig.rectified import RectifiedPair
from rig.stereo import StereoParams
from service.errors import SettingsError
from service.settings import Settings

__all__ = ["BASE_BYTES", "WARN_SHARE", "check_memory", "describe_pair", "ring_estimate", "service_estimate"]

log = logging.getLogger("service.memory")

#: RSS of the interpreter with numpy, OpenCV, FastAPI, uvicorn and the service imported, before
#: any frame (155 MiB measured on x86-64 Linux, Python 3.11), rounded up.
BASE_BYTES = 160 * MIB
#: A budget above this share of the memory left is allowed with a warning.
WARN_SHARE = 0.75
_CONNECTION_BUFFERS = 2 * 64 * 1024
_STREAM_SOCKET = 64 * 1024
_QUEUED_FRAME_BYTES = 2


def service_estimate(
    settings: Settings, rig: Rig, pair: RectifiedPair, stereo: StereoParams
) -> MemoryEstimate:
    """The budget of a service with ``settings`` for the cameras of ``rig``, the rectified pair
    ``pair`` (as designed: its real size) and the stereo parameters ``stereo`` (see module doc)."""
    sizes = [(rig.cameras[n].width, rig.cameras[n].height) for n in (pair.left, pair.right)]
    width, height = pair.camera.width, pair.camera.height
    parts = pipeline_parts((width, height), stereo, sizes, queued_frames_per_camera=_queued(settings))
    return _with_service(parts, settings, sum(w * h for w, h in sizes), width * height)


def ring_estimate(
    settings: Settings,
    rig: Rig,
    pairs: Sequence[RectifiedPair],
    stereo: StereoParams,
    panorama_size: tuple[int, int],
) -> MemoryEstimate:
    """:func:`service_estimate` of a rig of N cameras: every pair of ``pairs`` (as designed),
    each camera once, and the panorama of ``panorama_size`` (:func:`rig.memory_budget.ring_parts`)."""
    sizes = {n: (rig.cameras[n].width, rig.cameras[n].height) for n in rig.names}
    designed = [((p.camera.width, p.camera.height), (p.left, p.right)) for p in pairs]
    parts = ring_parts(designed, stereo, sizes, panorama_size, queued_frames_per_camera=_queued(settings))
    used = {n for p in pairs for n in (p.left, p.right)}
    camera_px = sum(w * h for n, (w, h) in sizes.items() if n in used)
    return _with_service(parts, settings, camera_px, max(w * h for (w, h), _ in designed))


def _queued(settings: Settings) -> int:
    pairing = settings.cameras.pairing if settings.cameras is not None else None
    return (pairing.buffer_size + pairing.pair_buffer) if pairing is not None else 12


def _with_service(
    parts: MemoryEstimate, settings: Settings, camera_px: int, stream_px: int
) -> MemoryEstimate:
    """``parts`` and the service's own: the recording queue of ``camera_px`` camera pixels per
    set, connections, streams of at most ``stream_px`` pixels a part, the interpreter."""
    server = settings.server
    return parts.plus(
        recording_queue=server.recording_queue * _QUEUED_FRAME_BYTES * camera_px,
        connections=server.max_connections * (server.max_body_bytes + _CONNECTION_BUFFERS),
        streams=server.max_streams * (stream_px + _STREAM_SOCKET),
        interpreter=BASE_BYTES,
    )


def describe_pair(pair: RectifiedPair, stereo: StereoParams) -> str:
    """``a 661x1064 lat-lon pair (5.585 px/deg) with 96 disparities``: what a budget is for."""
    c = pair.camera
    kind = (
        f"lat-lon pair ({math.radians(c.fx):.3f} px/deg)" if pair.projection == "latlon" else "pinhole pair"
    )
    return f"a {c.width}x{c.height} {kind} with {stereo.disparity_range} disparities"


def _smaller(pair: RectifiedPair) -> str:
    if pair.projection == "latlon":
        return "a lower rectified.px_per_deg or a narrower field (rectified.az_span_deg, el_span_deg)"
    return "a smaller rectified.width/rectified.height"


def check_memory(
    estimate: MemoryEstimate,
    pair: RectifiedPair,
    stereo: StereoParams,
    available: int | None = None,
    *,
    already_held: int = 0,
) -> None:
    """SettingsError if ``estimate`` exceeds the memory left (``available``, default: what
    :func:`rig.memory_budget.available_memory` finds, plus ``already_held``: what the running
    service's current budget holds and would give back, for a change); a warning above
    :data:`WARN_SHARE` of it."""
    room = available if available is not None else available_memory()
    if room is None:
        return
    room += already_held
    what = describe_pair(pair, stereo)
    need = f"about {estimate.total / MIB:.0f} MiB ({estimate.largest()})"
    if estimate.total > room:
        raise SettingsError(
            f"settings: field 'rectified': {what} needs {need}, more than the {room / MIB:.0f} MiB this "
            f"machine has left: choose {_smaller(pair)} (or stereo.disparity_range, "
            "server.recording_queue)"
        )
    if estimate.total > WARN_SHARE * room:
        log.warning("%s needs %s of the %.0f MiB this machine has left", what, need, room / MIB)
