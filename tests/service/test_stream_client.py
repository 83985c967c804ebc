"""/stream.mjpg read as a real multipart stream, and the client's error handling."""

from __future__ import annotations

import cv2
import httpx
import numpy as np
import pytest

from service.client import RigClient
from service.errors import ApiError, ServiceError
from tests.helpers.service import SMALL_SPEC, LiveServer

pytestmark = pytest.mark.timeout(120)


def read_parts(body: bytes, boundary: bytes) -> list[tuple[dict[str, str], bytes]]:
    """Split a multipart/x-mixed-replace body using each part's Content-Length."""
    parts = []
    pos = 0
    while True:
        start = body.find(b"--" + boundary + b"\r\n", pos)
        if start < 0:
            return parts
        head_end = body.index(b"\r\n\r\n", start)
        lines = body[start:head_end].decode("ascii").split("\r\n")[1:]
        headers = {k.strip().lower(): v.strip() for k, v in (line.split(":", 1) for line in lines)}
        n = int(headers["content-length"])
        data = body[head_end + 4 : head_end + 4 + n]
        assert body[head_end + 4 + n : head_end + 6 + n] == b"\r\n"
        parts.append((headers, data))
        pos = head_end + 4 + n


def test_mjpeg_stream_parts(shared_server: LiveServer) -> None:
    with httpx.stream(
        "GET", shared_server.base_url + "/stream.mjpg", params={"max_frames": 3}, timeout=30
    ) as r:
        assert r.status_code == 200
        ctype = r.headers["content-type"]
        assert ctype.startswith("multipart/x-mixed-replace")
        boundary = ctype.split("boundary=")[1].encode()
        body = r.read()
    parts = read_parts(body, boundary)
    assert len(parts) == 3
    seqs = []
    for headers, data in parts:
        assert (
            headers["content-type"] == "image/jpeg" and data[:2] == b"\xff\xd8" and data[-2:] == b"\xff\xd9"
        )
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        assert img.shape == (SMALL_SPEC.vpc.height, SMALL_SPEC.vpc.width, 3)
        assert float(headers["x-processing-ms"]) > 0 and float(headers["x-latency-ms"]) >= 0
        assert float(headers["x-timing-match-ms"]) > 0 and "x-timing-remap-ms" in headers
        assert int(headers["x-timestamp-ns"]) > 0
        seqs.append(int(headers["x-frame-seq"]))
    assert seqs == sorted(seqs) and len(set(seqs)) == 3  # three distinct, newer and newer frames


def test_stream_can_be_abandoned_midway(shared_server: LiveServer) -> None:
    with httpx.stream("GET", shared_server.base_url + "/stream.mjpg", timeout=30) as r:
        first = next(r.iter_bytes())
        assert first.startswith(b"--frame\r\n")
    # The server is still fine after a client hung up on an endless stream.
    assert httpx.get(shared_server.base_url + "/livez").status_code == 200


def test_client_errors_carry_status_and_detail(shared_server: LiveServer) -> None:
    with RigClient(shared_server.base_url) as c:
        with pytest.raises(ApiError) as info:
            c.frames("middle")
        assert info.value.status == 404 and "middle" in str(info.value.detail)
        assert isinstance(info.value, ServiceError)
        with pytest.raises(ApiError) as info:
            c.patch_config(median=3)  # no token given to this client
        assert info.value.status == 401
        with pytest.raises(ApiError) as info:
            c.pointcloud(stride=0)
        assert info.value.status == 422 and isinstance(info.value.detail, list)


def test_client_transport_failure_is_status_zero() -> None:
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now
    with RigClient(f"http://127.0.0.1:{port}", timeout=2) as c, pytest.raises(ApiError) as info:
        c.health()
    assert info.value.status == 0 and "Connect" in str(info.value.detail)
