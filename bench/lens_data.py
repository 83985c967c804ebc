"""The real fisheye images ``bench.lens_fit`` measures (``$RIG_SHARED_DATA``, default
``../shared/data``; never copied into the repository).

* **ring**: ``ring_sweepnet_indoor``, four ~226° fisheyes (OCamCalib models, 1600×1532 grey PNG),
  3 frames each; the field edge is the data's ``invisible_mask`` (112.9° off axis).
* **matsuren**: ``ocamcalib_matsuren``, one 1600×1600 colour JPEG of a corridor (OCamCalib
  model).
* **sourishg**: ``fisheye_stereo_sourishg``, 29 left and 29 right 960×600 colour JPEGs of a
  checkerboard room; no calibration, so the relative field is the radius over the image
  circle's (an equidistant lens's θ/θmax).

For the OCamCalib lenses θ comes from the model (``calibration.formats``); their field edge, where
no mask is given, is where the image circle ends (:func:`_circle`).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import scipy.io
from numpy.typing import NDArray

from calibration.formats import load_camera
from calibration.models import CameraModel

__all__ = ["FIELD_MARGIN", "LensCamera", "load_lenses", "shared_data"]

F64 = NDArray[np.float64]
Mask = NDArray[np.bool_]
U8 = NDArray[np.uint8]

#: Measurements stop this far inside the field edge (relative field): the circle's own edge.
FIELD_MARGIN = 0.03


@dataclass
class LensCamera:
    """One camera's images (grey uint8), each pixel's relative field ``x`` = θ/θmax and
    ``azimuth`` about the axis (radians), the pixels to measure, and (for a calibrated lens) its
    ``model`` and pixels per radian on the axis."""

    lens: str
    camera: str
    images: list[U8]
    x: F64
    azimuth: F64
    valid: Mask
    theta_max_deg: float
    model: CameraModel | None = None
    px_per_rad: float = math.nan


def shared_data() -> Path:
    return Path(
        os.environ.get("RIG_SHARED_DATA", Path(__file__).resolve().parent.parent.parent / "shared" / "data")
    )


def _grey(path: Path) -> U8:
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise FileNotFoundError(f"{path}: cannot read the image")
    return np.asarray(img, dtype=np.uint8)


def _angles(model: CameraModel) -> tuple[F64, F64]:
    """θ off the axis (NaN where the model has no ray) and the azimuth of every pixel."""
    v, u = np.mgrid[0 : model.height, 0 : model.width].astype(np.float64)
    rays, ok = model.unproject(np.stack([u.ravel(), v.ravel()], axis=1))
    theta = np.arccos(np.clip(rays[:, 2], -1.0, 1.0))
    theta[~ok] = np.nan
    azimuth = np.arctan2(rays[:, 1], rays[:, 0])
    return theta.reshape(model.height, model.width), azimuth.reshape(model.height, model.width)


def _px_per_rad(model: CameraModel) -> float:
    pts = np.array([[0.0, 0.0, 1.0], [math.sin(0.01), 0.0, math.cos(0.01)]])
    pix, _ = model.project(pts)
    return float(np.linalg.norm(pix[1] - pix[0]) / 0.01)


def _circle(images: list[U8], level: float) -> Mask:
    """The image circle: the convex hull of the largest region brighter than ``level`` (the black
    beyond the circle, lifted by JPEG, is darker) in the blurred mean image."""
    mean = np.mean(np.stack(images), axis=0).astype(np.float32)
    bright = (cv2.GaussianBlur(mean, (0, 0), 4.0) > level).astype(np.uint8)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(bright)
    biggest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    ys, xs = np.nonzero(labels == biggest)
    hull = cv2.convexHull(np.stack([xs, ys], axis=1).astype(np.int32))
    out = np.zeros(mean.shape, np.uint8)
    cv2.fillConvexPoly(out, hull, 1)
    return out.astype(bool)


def _fit_circle(inside: Mask) -> tuple[float, float, float]:
    """Centre and radius of the circle through the edge of ``inside`` where it is not the frame's
    (the sensor cuts the circle): Kåsa's least-squares fit."""
    edge = cv2.morphologyEx(inside.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3))).astype(bool)
    edge[:3], edge[-3:], edge[:, :3], edge[:, -3:] = False, False, False, False
    ys, xs = np.nonzero(edge)
    a = np.stack([xs, ys, np.ones_like(xs)], axis=1).astype(np.float64)
    b = xs.astype(np.float64) ** 2 + ys.astype(np.float64) ** 2
    (p, q, r), *_ = np.linalg.lstsq(a, b, rcond=None)
    cx, cy = p / 2.0, q / 2.0
    return float(cx), float(cy), float(math.sqrt(r + cx * cx + cy * cy))


def _edge_theta(theta: F64, inside: Mask) -> float:
    boundary = cv2.morphologyEx(inside.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3))).astype(bool)
    return float(np.nanmedian(theta[boundary & inside]))


def _calibrated(lens: str, camera: str, model: CameraModel, images: list[U8], inside: Mask) -> LensCamera:
    theta, azimuth = _angles(model)
    theta_max = _edge_theta(theta, inside)
    x = theta / theta_max
    valid = inside & np.isfinite(x) & (x <= 1.0 - FIELD_MARGIN)
    return LensCamera(
        lens, camera, images, np.nan_to_num(x, nan=2.0), azimuth, valid, math.degrees(theta_max), model,
        _px_per_rad(model),
    )  # fmt: skip


def _ring(root: Path) -> list[LensCamera]:
    mat = scipy.io.loadmat(root / "intrinsic_extrinsic.mat", squeeze_me=True, struct_as_record=False)
    out = []
    for k in range(1, 5):
        model = load_camera(root / f"ocam{k}.txt")
        images = [_grey(root / f"cam{k}" / f"0000{i}.png") for i in (1, 2, 3)]
        inside = np.asarray(mat["ocams"][k - 1].invisible_mask == 0)
        out.append(_calibrated("ring", f"cam{k}", model, images, inside))
    return out


def _sourishg(root: Path) -> list[LensCamera]:
    out = []
    for side in ("left", "right"):
        images = [_grey(root / "imgs" / f"{side}{i}.jpg") for i in range(1, 30)]
        inside = _circle(images, 25.0)
        cx, cy, radius = _fit_circle(inside)
        h, w = inside.shape
        v, u = np.mgrid[0:h, 0:w].astype(np.float64)
        x = np.hypot(u - cx, v - cy) / radius
        valid = inside & (x <= 1.0 - FIELD_MARGIN)
        out.append(LensCamera("sourishg", side, images, x, np.arctan2(v - cy, u - cx), valid, math.nan))
    return out


def load_lenses(root: Path | None = None) -> list[LensCamera]:
    """Every camera of the three data sets."""
    base = root or shared_data()
    matsuren = base / "ocamcalib_matsuren"
    mats_images = [_grey(matsuren / "img0.jpg")]
    mats = _calibrated(
        "matsuren",
        "cam0",
        load_camera(matsuren / "calib_results_0.txt"),
        mats_images,
        _circle(mats_images, 80.0),
    )
    return [*_ring(base / "ring_sweepnet_indoor"), mats, *_sourishg(base / "fisheye_stereo_sourishg")]
