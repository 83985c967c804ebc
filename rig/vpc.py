"""Virtual pinhole camera (VPC) pair cut out of the overlap of two fisheye cameras (docs/design.md).

The pair is derived from the calibrated extrinsics, not from the mount's nominal angles: the VPC x
axis is the baseline direction, so rows align exactly even on a mount that is 87° instead of 90°
or pitched. Because the image planes of a rectified pair must contain the baseline, a *yaw* of the
look direction cannot rotate the pair; it is realised as a horizontal principal-point shift (an
off-axis view whose centre pixel looks ``yaw_deg`` to the side). *Pitch* rotates the pair about the
baseline.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from pydantic import ConfigDict, Field

from calibration.geometry import make_transform, rot_x
from calibration.models import PinholeModel
from calibration.rig import Rig
from rig.errors import ConfigError
from rig.settings_model import SettingsModel

__all__ = ["VpcConfig", "VpcPair", "design_vpc_pair"]

F64 = NDArray[np.float64]


class VpcConfig(SettingsModel):
    """Size, field of view and look direction of the VPC pair (degrees in config, docs/design.md)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    width: int = Field(640, ge=16, le=8192, description="VPC image width (px)")
    height: int = Field(480, ge=16, le=8192, description="VPC image height (px)")
    hfov_deg: float = Field(90.0, gt=1.0, lt=179.0, description="horizontal field of view")
    yaw_deg: float = Field(0.0, ge=-80.0, le=80.0, description="look right (+) or left (-)")
    pitch_deg: float = Field(0.0, ge=-80.0, le=80.0, description="look up (+) or down (-)")
    left: str = Field("left", description="rig camera that forms the left image")
    right: str = Field("right", description="rig camera that forms the right image")


@dataclass(frozen=True)
class VpcPair:
    """A rectified pair: one pinhole model shared by both views, and their poses in the rig.

    ``T_rig_vpc[name]`` (4, 4) places each VPC at its fisheye camera's optical centre;
    ``R_cam_vpc[name]`` (3, 3) rotates VPC rays into that fisheye camera's frame, the ``R`` of
    ``p_fisheye = π_f(R · π_pinhole⁻¹(p_vpc))``.
    """

    camera: PinholeModel
    T_rig_vpc: dict[str, F64]
    R_cam_vpc: dict[str, F64]
    baseline_m: float
    left: str
    right: str

    @property
    def fx(self) -> float:
        return self.camera.fx

    def as_json(self) -> dict[str, float | int]:
        """``vpc.json`` of ``rig process`` (docs/design.md)."""
        c = self.camera
        return {
            "width": c.width,
            "height": c.height,
            "fx": c.fx,
            "fy": c.fy,
            "cx": c.cx,
            "cy": c.cy,
            "baseline_m": self.baseline_m,
        }


def vpc_intrinsics(config: VpcConfig) -> PinholeModel:
    """Square-pixel pinhole for the config; yaw shifts the principal point (see module doc)."""
    f = (config.width / 2.0) / math.tan(math.radians(config.hfov_deg) / 2.0)
    cx = (config.width - 1) / 2.0 - f * math.tan(math.radians(config.yaw_deg))
    cy = (config.height - 1) / 2.0
    return PinholeModel(config.width, config.height, fx=f, fy=f, cx=cx, cy=cy)


def design_vpc_pair(rig: Rig, config: VpcConfig | None = None) -> VpcPair:
    """Rectified VPC pair for ``rig`` (docs/design.md, "The VPC pair").

    x = baseline direction (left centre to right centre); z = mean of the two optical axes made
    orthogonal to x, then pitched about x; y = z × x.
    """
    config = config or VpcConfig()
    for name in (config.left, config.right):
        if name not in rig.cameras:
            raise ConfigError(f"vpc: rig has no camera '{name}' (cameras: {', '.join(rig.names)})")
    c_l, c_r = rig.center(config.left), rig.center(config.right)
    baseline = float(np.linalg.norm(c_r - c_l))
    if baseline <= 0.0:
        raise ConfigError("vpc: the two cameras share an optical centre; no stereo baseline")
    x = (c_r - c_l) / baseline
    look = rig.axis(config.left) + rig.axis(config.right)
    z = look - np.dot(look, x) * x
    if np.linalg.norm(z) < 1e-9:
        raise ConfigError("vpc: the mean optical axis is parallel to the baseline; no common view")
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    # Pitch up (+) turns z towards -y (y points down): rot_x(+pitch) maps z to (0, -sin, cos).
    R_rig_vpc = np.column_stack([x, y, z]) @ rot_x(math.radians(config.pitch_deg))
    T_rig_vpc = {
        config.left: make_transform(R_rig_vpc, c_l),
        config.right: make_transform(R_rig_vpc, c_r),
    }
    R_cam_vpc = {name: rig.T_rig_cam[name][:3, :3].T @ R_rig_vpc for name in (config.left, config.right)}
    return VpcPair(vpc_intrinsics(config), T_rig_vpc, R_cam_vpc, baseline, config.left, config.right)
