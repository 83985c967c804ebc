"""Depth that pinhole tools read correctly, resampled from the range of any rectified pair.

The default lat-lon pair's ``/depth`` is range along each ray, and its views are no pinhole:
depth_image_proc, Nav2's costmaps and RViz's depth cloud assume ``z`` on a pinhole image with
``plumb_bob`` intrinsics and would build a wrong cloud from it. :class:`PinholeDepthView` is a
distortion-free pinhole in the **left rectified frame** (same centre and axes: its CameraInfo's
frame is the left rectified view's, so no new transform is needed) over a configurable forward
field (:class:`PinholeDepthConfig`: width, height, horizontal field of view); each of its pixels
reads the pair's range along its own ray (:func:`rig.resample.sample_surface`: bilinear between
agreeing neighbours, never a blend across an edge) and gives ``z = range · ray_z`` (NaN where
the pair has no range). It is exact for the pixels' rays: the pinhole's rays are the lat-lon
view's, met at other pixel positions.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from pydantic import ConfigDict, Field

from calibration.models import PinholeModel
from rig.rectified import RectifiedPair
from rig.resample import sample_surface
from rig.settings_model import SettingsModel

__all__ = ["PinholeDepthConfig", "PinholeDepthView"]

F32 = NDArray[np.float32]


class PinholeDepthConfig(SettingsModel):
    """The pinhole depth image's size and field, about the rectified pair's forward axis."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    width: int = Field(640, ge=16, le=4096, description="image width (px)")
    height: int = Field(480, ge=16, le=4096, description="image height (px)")
    hfov_deg: float = Field(90.0, gt=1.0, lt=170.0, description="horizontal field of view")


class PinholeDepthView:
    """The pinhole depth of ``config`` cut from ``pair``'s range (see the module doc)."""

    def __init__(self, pair: RectifiedPair, config: PinholeDepthConfig | None = None) -> None:
        config = config or PinholeDepthConfig()
        f = (config.width / 2.0) / math.tan(math.radians(config.hfov_deg) / 2.0)
        self.pair = pair
        self.camera = PinholeModel(
            config.width, config.height, fx=f, fy=f, cx=(config.width - 1) / 2.0, cy=(config.height - 1) / 2.0
        )
        v, u = np.mgrid[0 : config.height, 0 : config.width]
        pix = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
        rays, _ = self.camera.unproject(pix)
        q, ok = pair.camera.project(rays, in_image=False)
        self._q = np.where(ok[:, None], q, np.nan)
        self._z = rays[:, 2]  # unit rays: z per metre of range

    def depth(self, range_m: F32) -> F32:
        """z (H, W) float32 metres on the pinhole of the pair's range map ``range_m`` (the left
        rectified view's, NaN invalid); NaN where there is none."""
        r = sample_surface(np.asarray(range_m, dtype=np.float64), self._q)
        out: F32 = (r * self._z).astype(np.float32).reshape(self.camera.height, self.camera.width)
        return out
