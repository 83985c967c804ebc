"""Epipolar lat-lon views: both fisheye images resampled onto one grid of epipolar planes, where
features are found and matched (docs/rectification.md).

The views are a lat-lon rectified pair (:func:`rig.rectified.design_rectified_pair` with the
``latlon`` projection: x along the baseline, y down, z forward; the field is the lenses'
overlap), designed and tabulated the way the depth pipeline's pair is (:class:`rig.in_effect.
PairGeometry`, tables from the LUT cache), at a resolution of their own: the measure runs in the
background and needs fewer pixels than depth. A view pixel ``(u, v)`` is the ray of longitude
``ψ = (u − cx) / fx`` (the angle within its epipolar plane, from the plane x = 0 towards the
baseline) and latitude ``φ = (v − cy) / fy`` (the epipolar plane's angle about the baseline)::

    d = (sin ψ, cos ψ · sin φ, cos ψ · cos φ)

so a point seen by both cameras lies on one row of the two views whenever the calibration is
right, whatever its angle off either lens's axis (past 90° too). The two views sample the same
rays through each camera's own model, so a patch looks alike in both (only parallax differs),
which is what makes descriptors match across lenses 90° apart.

A keypoint's ray is exact, not interpolated: :meth:`EpipolarViews.rays` turns view pixels into
unit rays in a camera's frame, the input of the relative-pose estimation.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.models import CameraModel
from calibration.rig import Rig
from rig.errors import ConfigError, PipelineError
from rig.in_effect import PairGeometry
from rig.lut import Lut
from rig.lut_cache import LutCache
from rig.rectified import RectifiedPairConfig

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

    ``scale`` multiplies the lenses' angular resolution on their axes (0.5: a quarter of the
    pixels), ``max_px_per_deg`` caps it (a cheap check on any camera). ``lon_deg`` / ``lat_deg``:
    the half extents of the field about the rectified axis (clipped to the lenses' overlap; None:
    the whole overlap), which keeps the matches off the lenses' rims. ``luts[name]`` maps each
    view pixel to its fisheye pixel; ``mask`` (H, W) uint8 is 255 where both cameras see, shrunk
    by a margin: where features are looked for. ``cache_dir``: the LUT cache (default: the
    pipeline's).
    """

    def __init__(
        self,
        rig: Rig,
        left: str = "left",
        right: str = "right",
        *,
        scale: float = 1.0,
        max_px_per_deg: float | None = None,
        lon_deg: float | None = 60.0,
        lat_deg: float | None = 80.0,
        cache_dir: str | Path | None = None,
    ) -> None:
        if not (math.isfinite(scale) and 0.05 <= scale <= 4.0):
            raise ConfigError(f"epipolar views: scale must be in [0.05, 4], got {scale!r}")
        self.names = (left, right)
        px_per_rad = scale * min(angular_resolution(rig.cameras[n]) for n in self.names if n in rig.cameras)
        if max_px_per_deg is not None:
            px_per_rad = min(px_per_rad, max_px_per_deg * 180.0 / math.pi)
        config = RectifiedPairConfig(
            projection="latlon",
            px_per_deg=max(0.5, round(math.radians(px_per_rad), 6)),
            az_span_deg=None if lon_deg is None else 2.0 * lon_deg,
            el_span_deg=None if lat_deg is None else 2.0 * lat_deg,
            left=left,
            right=right,
        )
        self.geometry = PairGeometry.build(rig, config, LutCache(cache_dir))
        camera = self.geometry.pair.camera
        self.px_per_rad = camera.fx
        self.R_cam_view = dict(self.geometry.pair.R_cam_rect)
        self.cameras = {n: rig.cameras[n] for n in self.names}
        self.luts: dict[str, Lut] = self.geometry.luts
        self.width, self.height = camera.width, camera.height
        both = (self.luts[left].valid & self.luts[right].valid).astype(np.uint8) * 255
        kernel = np.ones((2 * _MASK_MARGIN_PX + 1, 2 * _MASK_MARGIN_PX + 1), np.uint8)
        self.mask: U8 = np.asarray(cv2.erode(both, kernel), dtype=np.uint8)
        self.overlap_fraction = float(np.count_nonzero(self.mask)) / self.mask.size

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    def view_rays(self, pixels: F64) -> F64:
        """Unit rays (N, 3) in the view frame of view pixels (N, 2)."""
        rays, _ = self.geometry.pair.camera.unproject(
            np.asarray(pixels, dtype=np.float64).reshape(-1, 2), in_image=False
        )
        return rays

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
