"""Disparity to depth and range, point clouds and their file formats (docs/design.md, "Depth and
point clouds"; docs/wide-pair.md).

Depth is z in the left VPC frame, metres, float32, NaN invalid; ``Z = fx·B/d``, invalid where
d ≤ 0 (the pinhole pair). Range is the distance along each pixel's ray from the left view's
centre, metres, float32, NaN invalid, for either rectified projection (one function each):

* pinhole: ``range = Z·|(x_n, y_n, 1)|`` with ``x_n = (u − cx)/fx``, ``y_n = (v − cy)/fy``
  (:func:`depth_to_range`);
* lat-lon: a disparity is an azimuth difference ``δ = d/fx`` (radians) within the row's epipolar
  plane; the triangle left centre, right centre, point has the angle ``δ`` at the point and
  ``90° + α_R`` at the right centre (``α_R = α − δ``, ``α = (u − cx)/fx`` the left ray's
  azimuth), so by the law of sines ``range = B·cos(α − δ)/sin δ = B·(cos α·cot δ + sin α)``
  (mrcal's ``stereo_range``); invalid where d ≤ 0 or the triangle does not close (range ≤ 0).

The 16-bit PNG form of depth and range is millimetres with 0 = invalid (RealSense/DepthAI
convention); values beyond 65.535 m do not fit and are written as 0 (invalid), never saturated.
PLY: binary little-endian, ``x y z`` float32 (+ ``red green blue`` uchar).
:func:`pack_xyzrgb` is the one point layout of ROS ``PointCloud2``, Foxglove ``PointCloud`` and
PCD files (``x y z`` float32, colour as PCL's packed ``rgb``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.atomic import write_atomic
from calibration.models import CameraModel, LatLonModel, PinholeModel
from rig.errors import PipelineError
from rig.filters import fill_where

__all__ = [
    "MM",
    "XYZRGB_DTYPE",
    "depth_from_png_mm",
    "depth_points",
    "depth_to_png16",
    "depth_to_png_mm",
    "depth_to_range",
    "disparity_to_depth",
    "disparity_to_range",
    "latlon_range",
    "pack_xyzrgb",
    "pixel_ray_norms",
    "ply_bytes",
    "range_points",
    "read_ply",
    "to_units16",
    "write_ply",
]

F32 = NDArray[np.float32]
#: The unit of the 16-bit PNGs of ``rig process`` and of ROS's 16UC1 depth: one millimetre.
MM = 0.001


def disparity_to_depth(disparity: F32, fx: float, baseline_m: float, *, out: F32 | None = None) -> F32:
    """Depth (H, W) float32 m from disparity (H, W) px: ``fx·B/d``; NaN where d ≤ 0 or NaN.
    ``out``: an (H, W) float32 array (or view) to write the depth into, returned."""
    d = np.asarray(disparity, dtype=np.float32)
    depth = np.empty(d.shape, dtype=np.float32) if out is None else out
    with np.errstate(divide="ignore", invalid="ignore"):
        np.divide(np.float32(fx * baseline_m), d, out=depth)
    depth[d <= 0] = np.nan  # (few; NaN d already gave NaN)
    return depth


def latlon_range(disparity: F32, camera: LatLonModel, baseline_m: float, *, out: F32 | None = None) -> F32:
    """Range (H, W) float32 m along each pixel's ray from disparity (H, W) px (NaN invalid) of
    the lat-lon view ``camera``: ``B·(cos α·cot δ + sin α)``, δ = d/fx (see the module doc);
    NaN where d ≤ 0 or the range is not positive. ``out``: an (H, W) float32 array to write it
    into. (Any rows: the azimuth is per column.)"""
    az = camera.azimuths()
    b_cos = (baseline_m * np.cos(az)).astype(np.float32)
    b_sin = (baseline_m * np.sin(az)).astype(np.float32)
    d = np.asarray(disparity, dtype=np.float32)
    r = np.empty(d.shape, dtype=np.float32) if out is None else out
    with np.errstate(divide="ignore", invalid="ignore"):
        np.multiply(d, np.float32(1.0 / camera.fx), out=r)
        # numpy's tan leaves its vector loop for NaN input, and most frames are half NaN: 0
        # instead, whose range comes out inf and is dropped below with the NaN's.
        cv2.patchNaNs(r, 0.0)
        np.tan(r, out=r)
        np.divide(b_cos, r, out=r)
        r += b_sin
    ok = d > 0  # False for NaN
    ok &= r > 0  # the triangle closes
    ok &= r < np.inf  # δ so small that cot δ overflows float32
    fill_where(r, np.nan, ~ok)
    return r


def disparity_to_range(
    disparity: F32, camera: CameraModel, baseline_m: float, *, ray_norms: F32 | None = None
) -> F32:
    """Range (H, W) float32 m along each pixel's ray from disparity (H, W) px (NaN invalid) of
    the rectified view ``camera``: a pinhole (``ray_norms`` as :func:`depth_to_range`: rows of
    them for rows of disparity) or a lat-lon view (:func:`latlon_range`, any rows)."""
    if isinstance(camera, LatLonModel):
        return latlon_range(disparity, camera, baseline_m)
    if isinstance(camera, PinholeModel):
        return depth_to_range(disparity_to_depth(disparity, camera.fx, baseline_m), camera, ray_norms)
    raise PipelineError(f"no disparity-to-range formula for a {camera.name} view")


def to_units16(values: NDArray[Any], unit: np.floating[Any]) -> NDArray[np.uint16]:
    """uint16 of ``rint(values / unit)`` computed in ``unit``'s precision, 0 where that is not
    in 1…65535 (NaN, ±inf, ≤ 0, or too large: not saturated). Same shape as ``values``. The one
    quantisation of every 16-bit image of depth, range and disparity (files, HTTP, ROS).

    In place on one float temporary, casting only the valid values. On the 640×480 depth map
    0.39 ms CPU where ``np.where(ok, rint(x / unit), 0).astype`` took 1.0 ms, or 3.5 ms when its
    four float64 temporaries page-faulted back in after malloc had returned them to the OS."""
    with np.errstate(invalid="ignore", over="ignore"):
        units = np.divide(values, unit, dtype=unit.dtype)
        np.rint(units, out=units)
        ok = units > 0  # False for NaN too
        ok &= units <= 65535  # and for +inf
        out = np.zeros(units.shape, np.uint16)
        np.copyto(out, units, casting="unsafe", where=ok)
    return out


def depth_to_png16(depth: F32, scale_m: float) -> NDArray[np.uint16]:
    """Depth or range (H, W) float32 m → uint16 units of ``scale_m`` (0.001 = mm), 0 where invalid
    (NaN, ≤ 0) or beyond 65535 units (not saturated: a clipped depth would be a wrong depth).
    Divides in float64: in float32, dividing by a ``scale_m`` like 0.001 moves some values across
    a half unit (0.0065 m would give 6 mm instead of 7)."""
    return to_units16(depth, np.float64(scale_m))


def depth_to_png_mm(depth: F32) -> NDArray[np.uint16]:
    """:func:`depth_to_png16` in millimetres: 0 where invalid (NaN, ≤ 0) or beyond 65.535 m."""
    return depth_to_png16(depth, MM)


def depth_from_png_mm(png: NDArray[np.uint16]) -> F32:
    """Inverse of :func:`depth_to_png_mm`: float32 m, NaN where 0."""
    out = np.asarray(png, dtype=np.float32) * np.float32(MM)
    out[png == 0] = np.nan
    return out


def _valid_samples(image: F32, stride: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Rows and columns of the finite, positive pixels of every ``stride``-th row and column."""
    if stride < 1:
        raise PipelineError(f"point cloud stride must be >= 1, got {stride}")
    sub = image[::stride, ::stride]
    ok = np.isfinite(sub) & (sub > 0)
    r_idx, c_idx = np.nonzero(ok)
    return r_idx * stride, c_idx * stride


def _to_frame(pts: NDArray[np.float64], T_rig_rect: ArrayLike | None) -> NDArray[np.float32]:
    if T_rig_rect is not None:
        T = np.asarray(T_rig_rect, dtype=np.float64)
        pts = pts @ T[:3, :3].T + T[:3, 3]
    return pts.astype(np.float32)


def depth_points(
    depth: F32,
    camera: PinholeModel,
    T_rig_rect: ArrayLike | None = None,
    stride: int = 1,
) -> tuple[NDArray[np.float32], NDArray[np.intp]]:
    """3D points of the valid depth pixels: ray through the pixel scaled to z = depth.

    ``depth`` (H, W) float32 m, NaN invalid; ``camera`` the VPC pinhole (distortion-free);
    ``T_rig_rect`` (4, 4) maps the result into the rig frame (None: stay in the VPC frame).
    Returns points (N, 3) float32 and the flat pixel indices (N,) they came from.
    """
    rows, cols = _valid_samples(depth, stride)
    z = depth[rows, cols].astype(np.float64)
    v, u = rows.astype(np.float64), cols.astype(np.float64)
    pts = np.stack([(u - camera.cx) / camera.fx * z, (v - camera.cy) / camera.fy * z, z], axis=1)
    return _to_frame(pts, T_rig_rect), rows * depth.shape[1] + cols


def range_points(
    range_m: F32,
    camera: CameraModel,
    T_rig_rect: ArrayLike | None = None,
    stride: int = 1,
) -> tuple[NDArray[np.float32], NDArray[np.intp]]:
    """3D points of the valid range pixels: the pixel's unit ray (``camera.unproject``, any
    rectified projection) times its range. Arguments and result as :func:`depth_points`."""
    rows, cols = _valid_samples(range_m, stride)
    rays, _ = camera.unproject(np.stack([cols, rows], axis=1).astype(np.float64), in_image=False)
    pts = rays * range_m[rows, cols].astype(np.float64)[:, None]
    return _to_frame(pts, T_rig_rect), rows * range_m.shape[1] + cols


def pixel_ray_norms(camera: PinholeModel) -> F32:
    """(H, W) float32 length of each pixel's ray scaled to z = 1, ``√(1 + x² + y²)`` with
    ``x = (u − cx)/fx``, ``y = (v − cy)/fy`` (the pinhole's distortion-free rays)."""
    x = (np.arange(camera.width, dtype=np.float64) - camera.cx) / camera.fx
    y = (np.arange(camera.height, dtype=np.float64) - camera.cy) / camera.fy
    return np.sqrt(1.0 + x[None, :] ** 2 + y[:, None] ** 2).astype(np.float32)


def depth_to_range(depth: F32, camera: PinholeModel, ray_norms: F32 | None = None) -> F32:
    """Range (H, W) float32 m: distance from the camera centre along each pixel's ray,
    ``depth · |ray|`` (:func:`pixel_ray_norms`); NaN where depth is. ``ray_norms`` may be
    passed in when the caller keeps them (they depend on the camera only), or rows of them for
    rows of depth."""
    norms = pixel_ray_norms(camera) if ray_norms is None else ray_norms
    d = np.asarray(depth, dtype=np.float32)
    if d.shape != norms.shape:
        raise PipelineError(
            f"range: depth is {d.shape[1]}x{d.shape[0]}, camera {camera.width}x{camera.height}"
        )
    return np.multiply(d, norms, dtype=np.float32)


#: One point of :func:`pack_xyzrgb`: 16 bytes, little-endian. ``rgb`` is PCL's packed colour,
#: ``0xAARRGGBB`` as a little-endian uint32 (bytes B, G, R, A), as RViz and PCL read it.
XYZRGB_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])


def pack_xyzrgb(points: ArrayLike, colors: ArrayLike | None = None) -> NDArray[np.void]:
    """Points (N, 3) and colours (N, 3) uint8 RGB (None: white) as (N,) :data:`XYZRGB_DTYPE`
    records, alpha 255."""
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    out = np.empty(pts.shape[0], dtype=XYZRGB_DTYPE)
    out["x"], out["y"], out["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if colors is None:
        out["rgb"] = 0xFFFFFFFF
        return out
    rgb = np.asarray(colors, dtype=np.uint8).reshape(-1, 3)
    if rgb.shape[0] != pts.shape[0]:
        raise PipelineError(f"point cloud: {pts.shape[0]} points but {rgb.shape[0]} colours")
    packed = np.full(pts.shape[0], 0xFF000000, dtype=np.uint32)
    packed |= rgb[:, 0].astype(np.uint32) << 16
    packed |= rgb[:, 1].astype(np.uint32) << 8
    packed |= rgb[:, 2].astype(np.uint32)
    out["rgb"] = packed
    return out


def ply_bytes(points: ArrayLike, colors: ArrayLike | None = None) -> bytes:
    """Binary little-endian PLY: ``x y z`` float32 (+ ``red green blue`` uchar) per vertex, from
    points (N, 3) and colours (N, 3) uint8 RGB, built in memory."""
    pts = np.asarray(points, dtype="<f4").reshape(-1, 3)
    props = ["property float x", "property float y", "property float z"]
    dtype: list[tuple[str, str]] = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    rgb = None
    if colors is not None:
        rgb = np.asarray(colors, dtype=np.uint8).reshape(-1, 3)
        if rgb.shape[0] != pts.shape[0]:
            raise PipelineError(f"PLY: {pts.shape[0]} points but {rgb.shape[0]} colours")
        props += ["property uchar red", "property uchar green", "property uchar blue"]
        dtype += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rec = np.empty(pts.shape[0], dtype=dtype)
    rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if rgb is not None:
        rec["red"], rec["green"], rec["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    header = "\n".join(
        ["ply", "format binary_little_endian 1.0", f"element vertex {pts.shape[0]}", *props, "end_header"]
    )
    return header.encode("ascii") + b"\n" + rec.tobytes()


def write_ply(path: str | Path, points: ArrayLike, colors: ArrayLike | None = None) -> Path:
    """:func:`ply_bytes` of points (N, 3) (+ colours (N, 3) uint8 RGB) written atomically."""
    path = Path(path)
    write_atomic(path, ply_bytes(points, colors), fsync=False)
    return path


_PLY_TYPES = {"float": "<f4", "float32": "<f4", "double": "<f8", "uchar": "u1", "uint8": "u1"}


def read_ply(path: str | Path) -> tuple[NDArray[np.float32], NDArray[np.uint8] | None]:
    """Read what :func:`write_ply` writes (binary little-endian vertex x y z [red green blue])."""
    path = Path(path)
    data = path.read_bytes()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise PipelineError(f"{path}: not a PLY file")
    lines = data[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise PipelineError(f"{path}: only binary little-endian PLY is read")
    count = 0
    fields: list[tuple[str, str]] = []
    for line in lines:
        parts = line.split()
        if parts[:2] == ["element", "vertex"]:
            count = int(parts[2])
        elif parts[:1] == ["property"] and len(parts) == 3:
            if parts[1] not in _PLY_TYPES:
                raise PipelineError(f"{path}: unsupported PLY property type {parts[1]!r}")
            fields.append((parts[2], _PLY_TYPES[parts[1]]))
    rec: Any = np.frombuffer(data, dtype=np.dtype(fields), count=count, offset=end + len(b"end_header\n"))
    pts = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float32)
    names = {n for n, _ in fields}
    cols = None
    if {"red", "green", "blue"} <= names:
        cols = np.stack([rec["red"], rec["green"], rec["blue"]], axis=1).astype(np.uint8)
    return pts, cols
