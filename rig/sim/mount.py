"""The orthogonally divergent mount: two cameras a baseline apart, axes yawed apart; and a ring
of N such cameras on a regular polygon."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from calibration.geometry import make_transform, rot_x, rot_y, rot_z
from calibration.models import CameraModel
from calibration.rig import Rig
from rig.errors import ConfigError

__all__ = ["divergent_rig", "ring_rig"]


def divergent_rig(
    left: CameraModel,
    right: CameraModel,
    baseline_m: float,
    angle_deg: float = 90.0,
    pitch_deg: float = 0.0,
    roll_deg: float = 0.0,
) -> Rig:
    """Rig with cameras "left" at (-B/2, 0, 0) yawed -angle/2 (looking left-forward) and "right"
    at (+B/2, 0, 0) yawed +angle/2; the rig's z axis bisects the optical axes.

    ``pitch_deg`` (up +, about the right camera's own x axis) and ``roll_deg`` (about its optical
    axis, clockwise in its image +) tilt the RIGHT camera only, modelling a non-ideal mount:
    ``R_rig_right = rot_y(angle/2) · rot_x(pitch) · rot_z(roll)``.
    """
    b, angle, pitch, roll = (float(v) for v in (baseline_m, angle_deg, pitch_deg, roll_deg))
    if not (math.isfinite(b) and b > 0):
        raise ConfigError(f"mount: baseline_m must be a positive number of metres, got {baseline_m!r}")
    if not (math.isfinite(angle) and 0 <= angle < 180):
        raise ConfigError(f"mount: angle_deg must be in [0, 180), got {angle_deg!r}")
    for name, v in (("pitch_deg", pitch), ("roll_deg", roll)):
        if not (math.isfinite(v) and abs(v) <= 90):
            raise ConfigError(f"mount: {name} must be within ±90, got {v!r}")
    half = math.radians(angle) / 2.0
    R_left = rot_y(-half)
    # y points down: rot_x(+pitch) turns z (0, 0, 1) into (0, -sin, cos), i.e. up.
    R_right = rot_y(half) @ rot_x(math.radians(pitch)) @ rot_z(math.radians(roll))
    return Rig(
        {"left": left, "right": right},
        {
            "left": make_transform(R_left, np.array([-b / 2.0, 0.0, 0.0])),
            "right": make_transform(R_right, np.array([b / 2.0, 0.0, 0.0])),
        },
    )


def ring_rig(lenses: Sequence[CameraModel], baseline_m: float) -> Rig:
    """Rig of N = len(lenses) ≥ 3 cameras ``cam1``..``camN`` on the corners of a regular polygon
    of side ``baseline_m`` in the horizontal plane (y = 0), each looking out of the polygon's
    centre (the origin) through its corner, so neighbours are 360°/N apart, clockwise seen from
    above. ``cam1`` looks 180°/N left of the rig's z, ``cam2`` as far right: the pair cam1|cam2 is
    :func:`divergent_rig`'s left|right at the same baseline (for N = 4, the 90° mount)."""
    n, b = len(lenses), float(baseline_m)
    if n < 3:
        raise ConfigError(f"mount: a ring needs at least 3 cameras, got {n}")
    if not (math.isfinite(b) and b > 0):
        raise ConfigError(f"mount: baseline_m must be a positive number of metres, got {baseline_m!r}")
    radius = b / 2.0 / math.sin(math.pi / n)
    cameras, poses = {}, {}
    for k, lens in enumerate(lenses):
        azimuth = 2.0 * math.pi * k / n - math.pi / n
        name = f"cam{k + 1}"
        cameras[name] = lens
        poses[name] = make_transform(
            rot_y(azimuth), np.array([radius * math.sin(azimuth), 0.0, radius * math.cos(azimuth)])
        )
    return Rig(cameras, poses)
