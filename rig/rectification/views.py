"""Epipolar lat-lon views: both fisheye images resampled onto one grid of epipolar planes, where
features are found and matched (docs/rectification.md).

The view frame is the rectified pair's (:func:`rig.rectified.design_rectified_pair`: x along the baseline,
y down, z forward). A view pixel ``(u, v)`` is the ray of longitude ``ψ = (u − cu) / s`` (the
angle within its epipolar plane, from the plane x = 0 towards the baseline) and latitude
``φ = (v − cv) / s`` (the epipolar plane's angle about the baseline)::

    d = (sin ψ, cos ψ · sin φ, cos ψ · cos φ)

so a point seen by both cameras lies on one row of the two views whenever the calibration is
right, whatever its angle off either lens's axis (past 90° too): the same rows a pinhole
rectified pair has, over the whole overlap of two 190° lenses. The two views sample the same
rays through each camera's own model, so a patch looks alike in both (only parallax differs),
which is what makes descriptors match across lenses 90° apart. ``s`` is the lenses' angular
resolution on their axes (px/rad) times ``scale``.

A keypoint's ray is exact, not interpolated: :meth:`EpipolarViews.rays` turns view pixels into
unit rays in a camera's frame, the input of the relative-pose estimation.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.models import CameraModel
from calibration.rig import Rig
from rig.errors import ConfigError, PipelineError
from rig.lut import INVALID_COORD, Lut
from rig.rectified import RectifiedPairConfig, design_rectified_pair

__all__ = ["EpipolarViews", "angular_resolution"]

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

# Angle off axis (rad) at which a lens's angular resolution is measured.
_AXIS_STEP = 0.01
# Detection mask: the overlap shrunk by this many view pixels (keypoints need a whole patch).
_MASK_MARGIN_PX = 8


def angular_resolution(model: CameraModel) -> float:
    """Pixels per radian of ``model`` near its optical axis (mean of the x and y directions)."""
    rays = np.array([[0.0, 0.0, 1.0], [math.sin(_AXIS_STEP), 0.0, math.cos(_AXIS_STEP)],
                     [0.0, math.sin(_AXIS_STEP), math.cos(_AXIS_STEP)]])  # fmt: skip
    pix, ok = model.project(rays, in_image=False)
    if not ok.all():
        raise ConfigError(f"a {model.name} camera does not see along its own optical axis")
    return float(np.mean(np.linalg.norm(pix[1:] - pix[0], axis=1)) / _AXIS_STEP)


class EpipolarViews:
    """The lat-lon views of cameras ``left`` and ``right`` of ``rig`` (see module doc).

    ``lon_deg`` / ``lat_deg``: half extents of the grid; ``scale`` multiplies the lenses'
    angular resolution (0.5: a quarter of the pixels), ``max_px_per_deg`` caps it (a cheap
    check on any camera). ``luts[name]`` maps
    each view pixel to its fisheye pixel; ``mask`` (H, W) uint8 is 255 where both cameras see,
    shrunk by a margin: where features are looked for.
    """

    def __init__(
        self,
        rig: Rig,
        left: str = "left",
        right: str = "right",
        *,
        scale: float = 1.0,
        max_px_per_deg: float | None = None,
        lon_deg: float = 60.0,
        lat_deg: float = 80.0,
    ) -> None:
        if not (math.isfinite(scale) and 0.05 <= scale <= 4.0):
            raise ConfigError(f"epipolar views: scale must be in [0.05, 4], got {scale!r}")
        if not (0.0 < lon_deg < 90.0 and 0.0 < lat_deg <= 90.0):
            raise ConfigError(
                f"epipolar views: lon_deg must be in (0, 90) and lat_deg in (0, 90], got {lon_deg}, {lat_deg}"
            )
        pair = design_rectified_pair(rig, RectifiedPairConfig(left=left, right=right))
        self.names = (left, right)
        self.R_cam_view = {n: pair.R_cam_rect[n] for n in self.names}
        self.cameras = {n: rig.cameras[n] for n in self.names}
        self.px_per_rad = scale * min(angular_resolution(c) for c in self.cameras.values())
        if max_px_per_deg is not None:
            self.px_per_rad = min(self.px_per_rad, max_px_per_deg * 180.0 / math.pi)
        s = self.px_per_rad
        self.width = 2 * round(math.radians(lon_deg) * s) + 1
        self.height = 2 * round(math.radians(lat_deg) * s) + 1
        self.cu, self.cv = (self.width - 1) / 2.0, (self.height - 1) / 2.0
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        d = self.view_rays(np.stack([u.ravel(), v.ravel()], axis=1))
        self.luts: dict[str, Lut] = {}
        for name in self.names:
            cam = d @ self.R_cam_view[name].T
            pix, ok = self.cameras[name].project(cam)
            map_x = np.where(ok, pix[:, 0], INVALID_COORD).astype(np.float32).reshape(self.height, self.width)
            map_y = np.where(ok, pix[:, 1], INVALID_COORD).astype(np.float32).reshape(self.height, self.width)
            self.luts[name] = Lut.from_float_maps(map_x, map_y, ok.reshape(self.height, self.width))
        both = (self.luts[left].valid & self.luts[right].valid).astype(np.uint8) * 255
        kernel = np.ones((2 * _MASK_MARGIN_PX + 1, 2 * _MASK_MARGIN_PX + 1), np.uint8)
        self.mask: U8 = np.asarray(cv2.erode(both, kernel), dtype=np.uint8)
        self.overlap_fraction = float(np.count_nonzero(self.mask)) / self.mask.size

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    def view_rays(self, pixels: F64) -> F64:
        """Unit rays (N, 3) in the view frame of view pixels (N, 2)."""
        p = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        lon = (p[:, 0] - self.cu) / self.px_per_rad
        lat = (p[:, 1] - self.cv) / self.px_per_rad
        c = np.cos(lon)
        return np.stack([np.sin(lon), c * np.sin(lat), c * np.cos(lat)], axis=1)

    def rays(self, name: str, pixels: F64) -> F64:
        """Unit rays (N, 3) in camera ``name``'s frame of its view's pixels (N, 2)."""
        return self.view_rays(pixels) @ self.R_cam_view[name].T

    def remap(self, name: str, gray: U8) -> U8:
        """Camera ``name``'s view from its gray fisheye image (black where the lens sees nothing)."""
        model = self.cameras[name]
        if gray.ndim != 2 or gray.dtype != np.uint8 or gray.shape != (model.height, model.width):
            raise PipelineError(
                f"{name} image must be gray uint8 of its calibration's size {model.width}x{model.height}, "
                f"got {gray.dtype} {gray.shape}"
            )
        return self.luts[name].remap(gray)
