"""The service's memory budget: the pipeline's parts (:mod:`rig.memory_budget`) and the service's
own, from the settings and the calibrated camera sizes, known before anything is built.

:func:`check_memory` refuses at start-up a configuration whose budget exceeds the memory the
machine has left (one line naming the VPC size and the largest parts) and warns above
:data:`WARN_SHARE` of it. The running service exports the budget (``rig_memory_budget_bytes`` in
``/metrics``); its resident size stays under it (docs/reliability.md, "Memory budget").

The service's parts: frames waiting for the recording writer (``server.recording_queue`` pairs,
raw and gray: 2 bytes per camera pixel), HTTP connections (a request body and uvicorn's 64 KiB
read and write buffers each), streams (a part of at most one byte per VPC pixel and the socket's
send buffer each), and the interpreter with its libraries loaded (:data:`BASE_BYTES`).
"""

from __future__ import annotations

import logging

from calibration.rig import Rig
from rig.memory_budget import MIB, MemoryEstimate, available_memory, pipeline_parts
from service.errors import SettingsError
from service.settings import Settings

__all__ = ["BASE_BYTES", "WARN_SHARE", "check_memory", "service_estimate"]

log = logging.getLogger("service.memory")

#: RSS of the interpreter with numpy, OpenCV, FastAPI, uvicorn and the service imported, before
#: any frame (155 MiB measured on x86-64 Linux, Python 3.11), rounded up.
BASE_BYTES = 160 * MIB
#: A budget above this share of the memory left is allowed with a warning.
WARN_SHARE = 0.75
_CONNECTION_BUFFERS = 2 * 64 * 1024
_STREAM_SOCKET = 64 * 1024
_QUEUED_FRAME_BYTES = 2


def service_estimate(settings: Settings, rig: Rig) -> MemoryEstimate:
    """The budget of a service with ``settings`` for the cameras of ``rig`` (see module doc)."""
    names = (settings.vpc.left, settings.vpc.right)
    sizes = [(rig.cameras[n].width, rig.cameras[n].height) for n in names if n in rig.cameras]
    server = settings.server
    pairing = settings.cameras.pairing if settings.cameras is not None else None
    queued = (pairing.buffer_size + pairing.pair_buffer) if pairing is not None else 12
    parts = pipeline_parts(settings.vpc, settings.stereo, sizes, queued_frames_per_camera=queued)
    camera_px = sum(w * h for w, h in sizes)
    rect_px = settings.vpc.width * settings.vpc.height
    return parts.plus(
        recording_queue=server.recording_queue * _QUEUED_FRAME_BYTES * camera_px,
        connections=server.max_connections * (server.max_body_bytes + _CONNECTION_BUFFERS),
        streams=server.max_streams * (rect_px + _STREAM_SOCKET),
        interpreter=BASE_BYTES,
    )


def check_memory(settings: Settings, estimate: MemoryEstimate, available: int | None = None) -> None:
    """SettingsError if ``estimate`` exceeds the memory left (``available``, default: what
    :func:`rig.memory_budget.available_memory` finds); a warning above :data:`WARN_SHARE` of it."""
    room = available if available is not None else available_memory()
    if room is None:
        return
    vpc, stereo = settings.vpc, settings.stereo
    what = f"a {vpc.width}x{vpc.height} VPC with {stereo.disparity_range} disparities"
    need = f"about {estimate.total / MIB:.0f} MiB ({estimate.largest()})"
    if estimate.total > room:
        raise SettingsError(
            f"settings: field 'vpc': {what} needs {need}, more than the {room / MIB:.0f} MiB this "
            "machine has left: choose a smaller vpc.width/vpc.height (or stereo.disparity_range, "
            "server.recording_queue)"
        )
    if estimate.total > WARN_SHARE * room:
        log.warning("%s needs %s of the %.0f MiB this machine has left", what, need, room / MIB)
