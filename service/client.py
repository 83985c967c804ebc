"""Typed Python client of the depth service (httpx).

```python
from service.client import RigClient

with RigClient("http://127.0.0.1:8000") as rig:
    print(rig.health().status)
    d = rig.depth()                  # float32 metres, NaN = invalid
    print(d.seq, d.depth.shape, float(np.nanmedian(d.depth)))
    r = rig.range()                  # metres along each pixel's ray (either projection)
    left = rig.frames("left", "rectified")  # the rectified left image
```

Every failed request raises :class:`service.errors.ApiError` with the HTTP status and the
server's ``detail``; transport failures raise it with status 0.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Any, Literal

import cv2
import httpx
import numpy as np
from numpy.typing import NDArray

from service.errors import ApiError
from service.schemas import CalibrationModel, ConfigModel, HealthModel, RecordingInfo

__all__ = [
    "ConfidenceMap",
    "DepthMap",
    "DisparityMap",
    "FrameImage",
    "PointCloud",
    "RangeMap",
    "RigClient",
]


@dataclass(frozen=True)
class DepthMap:
    """``depth`` (H, W) float32 metres, NaN invalid; ``scale`` metres per unit of the body that
    was transferred (0.001 for a mm PNG, 1.0 for npy)."""

    depth: NDArray[np.float32]
    seq: int
    ts_ns: int
    scale: float


@dataclass(frozen=True)
class RangeMap:
    """``range`` (H, W) float32 metres along each left rectified pixel's ray, NaN invalid;
    ``scale`` metres per unit of the body that was transferred (0.001 for a mm PNG, 1.0 for
    npy)."""

    range: NDArray[np.float32]
    seq: int
    ts_ns: int
    scale: float


@dataclass(frozen=True)
class DisparityMap:
    """``disparity`` (H, W) float32 px of the left VPC image, NaN invalid."""

    disparity: NDArray[np.float32]
    seq: int
    ts_ns: int


@dataclass(frozen=True)
class ConfidenceMap:
    confidence: NDArray[np.float32]  # [0, 1], 0 where depth is invalid
    seq: int
    ts_ns: int


@dataclass(frozen=True)
class FrameImage:
    """One camera's image (``view`` raw or vpc) or the colour-mapped depth (``view`` depth)."""

    image: NDArray[np.uint8]
    seq: int
    ts_ns: int
    camera: str
    view: str


@dataclass(frozen=True)
class PointCloud:
    """``points`` (N, 3) float32 in the rig frame (m); ``colors`` (N, 3) uint8 RGB or None."""

    points: NDArray[np.float32]
    colors: NDArray[np.uint8] | None
    seq: int
    ts_ns: int


def _frame_meta(response: httpx.Response) -> tuple[int, int]:
    return int(response.headers["X-Frame-Seq"]), int(response.headers["X-Timestamp-Ns"])


def _load_npy(data: bytes) -> NDArray[Any]:
    return np.lib.format.read_array(io.BytesIO(data), allow_pickle=False)


def _decode_image(data: bytes, url: str) -> NDArray[Any]:
    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ApiError(200, "response body is not a decodable image", url)
    return img


def parse_ply(data: bytes) -> tuple[NDArray[np.float32], NDArray[np.uint8] | None]:
    """Binary little-endian PLY vertices (x y z float [red green blue uchar]) from bytes."""
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise ApiError(200, "response body is not a PLY file")
    header = data[:end].decode("ascii").splitlines()
    count = next(int(line.split()[2]) for line in header if line.startswith("element vertex"))
    types = {"float": "<f4", "uchar": "u1"}
    fields = [(p.split()[2], types[p.split()[1]]) for p in header if p.startswith("property")]
    rec: Any = np.frombuffer(data, dtype=np.dtype(fields), count=count, offset=end + len(b"end_header\n"))
    pts = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float32)
    names = {n for n, _ in fields}
    cols = (
        np.stack([rec["red"], rec["green"], rec["blue"]], axis=1)
        if {"red", "green", "blue"} <= names
        else None
    )
    return pts, cols


class RigClient:
    """Client of one depth service; a context manager (closes its connection pool)."""

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8000",
        token: str | None = None,
        timeout: float = 10.0,
        *,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self._http = httpx.Client(base_url=base_url, timeout=timeout, headers=headers, transport=transport)

    def __enter__(self) -> RigClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    # ----- plumbing ----------------------------------------------------------------------------
    def _request(self, method: str, path: str, *, ok: tuple[int, ...] = (200,), **kw: Any) -> httpx.Response:
        try:
            response = self._http.request(method, path, **kw)
        except httpx.HTTPError as err:
            raise ApiError(0, f"{type(err).__name__}: {err}", path) from err
        if response.status_code not in ok:
            try:
                detail = response.json().get("detail", response.text)
            except ValueError:
                detail = response.text
            raise ApiError(response.status_code, detail, path)
        return response

    # ----- reading -----------------------------------------------------------------------------
    def health(self) -> HealthModel:
        """The health document; also on 503 ("down"), which is an answer, not an error."""
        return HealthModel.model_validate_json(self._request("GET", "/health", ok=(200, 503)).content)

    def ready(self) -> bool:
        return self._request("GET", "/readyz", ok=(200, 503)).status_code == 200

    def _array(
        self, path: str, format: Literal["npy", "png"], scale_header: str
    ) -> tuple[NDArray[np.float32], NDArray[Any] | None, int, int, float]:
        """GET an array endpoint (``/depth``, ``/range``, ``/disparity``, ``/confidence``) in ``format``:
        float32 values (npy as sent; png units × the scale header), the png's units (None for
        npy: for the caller's invalid marking), the frame's seq and timestamp, and the scale."""
        r = self._request("GET", path, params={"format": format})
        seq, ts = _frame_meta(r)
        scale = float(r.headers[scale_header])
        if format == "npy":
            return _load_npy(r.content).astype(np.float32, copy=False), None, seq, ts, scale
        units = _decode_image(r.content, path)
        return units.astype(np.float32) * np.float32(scale), units, seq, ts, scale

    def depth(self, format: Literal["npy", "png"] = "npy") -> DepthMap:
        """Latest depth in metres (NaN invalid), whichever encoding is transferred: z for the
        pinhole pair, the range along each ray for the lat-lon pair."""
        return DepthMap(*self._metres("/depth", format, "X-Depth-Scale"))

    def range(self, format: Literal["npy", "png"] = "npy") -> RangeMap:
        """Latest range in metres along each pixel's ray (NaN invalid), either projection."""
        return RangeMap(*self._metres("/range", format, "X-Range-Scale"))

    def _metres(
        self, path: str, format: Literal["npy", "png"], scale_header: str
    ) -> tuple[NDArray[np.float32], int, int, float]:
        """``/depth`` or ``/range`` in metres, NaN where the png holds 0; seq, timestamp, scale."""
        values, units, seq, ts, scale = self._array(path, format, scale_header)
        if units is not None:
            values[units == 0] = np.nan
        return values, seq, ts, scale

    def disparity(self, format: Literal["npy", "png"] = "npy") -> DisparityMap:
        disp, units, seq, ts, _ = self._array("/disparity", format, "X-Disparity-Scale")
        if units is not None:
            disp[units == 0] = np.nan
        return DisparityMap(disp, seq, ts)

    def confidence(self, format: Literal["npy", "png"] = "npy") -> ConfidenceMap:
        """Latest confidence map in [0, 1] (0 where depth is invalid)."""
        conf, units, seq, ts, _ = self._array("/confidence", format, "X-Confidence-Scale")
        if units is not None:
            np.minimum(conf, np.float32(1.0), out=conf)  # 255 = 1 (the header's 1/255 is rounded)
        return ConfidenceMap(conf, seq, ts)

    def frames(self, camera: str, view: Literal["raw", "rectified", "vpc"] = "rectified") -> FrameImage:
        r = self._request("GET", f"/frames/{camera}", params={"view": view})
        seq, ts = _frame_meta(r)
        return FrameImage(_decode_image(r.content, f"/frames/{camera}"), seq, ts, camera, view)

    def depth_colorized(self) -> FrameImage:
        r = self._request("GET", "/depth/colorized")
        seq, ts = _frame_meta(r)
        return FrameImage(_decode_image(r.content, "/depth/colorized"), seq, ts, "left", "depth")

    def pointcloud(self, stride: int = 1) -> PointCloud:
        r = self._request("GET", "/pointcloud", params={"stride": stride})
        seq, ts = _frame_meta(r)
        points, colors = parse_ply(r.content)
        return PointCloud(points, colors, seq, ts)

    def calibration(self) -> CalibrationModel:
        return CalibrationModel.model_validate_json(self._request("GET", "/calibration").content)

    def config(self) -> ConfigModel:
        return ConfigModel.model_validate_json(self._request("GET", "/config").content)

    def config_revision(self) -> tuple[ConfigModel, str]:
        """The configuration and its revision (``/config``'s ETag), for a conditional
        :meth:`patch_config` (read, decide, change only if nobody changed it meanwhile)."""
        r = self._request("GET", "/config")
        return ConfigModel.model_validate_json(r.content), r.headers["etag"]

    def metrics(self) -> str:
        return self._request("GET", "/metrics").text

    # ----- changing (bearer token) -------------------------------------------------------------
    def patch_config(self, *, if_match: str | None = None, **stereo: Any) -> ConfigModel:
        """Change stereo parameters (rig.stereo.StereoParams names); returns the new config.
        ``if_match``: a revision from :meth:`config_revision`; the change applies only to it, else
        :class:`ApiError` 412 and nothing changed."""
        headers = {"If-Match": if_match} if if_match is not None else {}
        r = self._request("PATCH", "/config", json={"stereo": stereo}, headers=headers)
        return ConfigModel.model_validate_json(r.content)

    def start_recording(self, name: str) -> RecordingInfo:
        r = self._request("POST", "/recordings", json={"name": name}, ok=(201,))
        return RecordingInfo.model_validate_json(r.content)

    def stop_recording(self, name: str | None = None) -> RecordingInfo:
        """Stop recording ``name`` (default: the one running)."""
        if name is None:
            running = [r for r in self.recordings() if r.active]
            if not running:
                raise ApiError(404, "no recording is running", "/recordings")
            name = running[0].name
        r = self._request("POST", f"/recordings/{name}/stop")
        return RecordingInfo.model_validate_json(r.content)

    def recordings(self) -> list[RecordingInfo]:
        r = self._request("GET", "/recordings")
        return [RecordingInfo.model_validate(d) for d in r.json()]
