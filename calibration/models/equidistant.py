"""Ideal equidistant fisheye ("atan" in the paper): ``rd = θ``. The paper's simulated lens."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from calibration.models.base import Mask, register
from calibration.models.radial import RadialThetaModel

__all__ = ["EquidistantModel"]

F64 = NDArray[np.float64]


@register
class EquidistantModel(RadialThetaModel):
    name = "equidistant"
    param_names = ("fx", "fy", "cx", "cy")

    def _setup(self) -> None:
        self._setup_intrinsics()

    def _model_max_theta(self) -> float:
        return math.pi

    def radius(self, theta: F64) -> F64:
        return theta

    def theta_from_radius(self, rd: F64) -> tuple[F64, Mask]:
        return rd.copy(), rd < self.max_theta * (1.0 + 1e-12)
