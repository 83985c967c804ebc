"""Shared pieces of the rectification tests on renders: a small textured room recorded by the
prototype rig, calibrations perturbed from its truth, and the vertical disparity a calibration
really causes, from the render's ground-truth depth (independent of any feature matching)."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from calibration.geometry import invert_transform, rot_x, rot_y, rot_z, rotation_angle
from calibration.models import PinholeModel
from calibration.rig import Rig
from rig.depth import depth_points
from rig.rectification.measure import rectified_rows
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from rig.sim import get_preset, simulate_recording

#: Half-size prototype renders (640x480 fisheye), a VPC of the matching resolution.
SCALE = 0.5
VPC = RectifiedPairConfig(width=320, height=240)
GT_VPC = RectifiedPairConfig(width=160, height=120)


def render_room(out: Path, frames: int = 2, truth: Rig | None = None) -> Path:
    """The prototype (half size) in the textured room, through its honest lens (``rig sim``'s
    default: blur growing to the rim, rim darkening, the two cameras' exposures, noise)."""
    preset = get_preset("prototype").scaled(SCALE)
    if truth is not None:
        preset = replace(preset, rig=truth)
    return simulate_recording(preset, "room", out, frames=frames, supersample=2, vpc=GT_VPC)


def nominal_rig() -> Rig:
    return get_preset("prototype").scaled(SCALE).rig


def perturbed(rig: Rig, deg: tuple[float, float, float], along_baseline_m: float = 0.0) -> Rig:
    """``rig`` with the right camera turned by ``deg`` about the rig's x, y, z (degrees) and
    moved ``along_baseline_m`` along the baseline (which changes no direction)."""
    T = rig.T_rig_cam["right"].copy()
    T[:3, :3] = (
        rot_x(math.radians(deg[0])) @ rot_y(math.radians(deg[1])) @ rot_z(math.radians(deg[2])) @ T[:3, :3]
    )
    b = T[:3, 3] - rig.T_rig_cam["left"][:3, 3]
    T[:3, 3] += along_baseline_m * b / np.linalg.norm(b)
    return Rig(dict(rig.cameras), {"left": rig.T_rig_cam["left"].copy(), "right": T})


def relative_rotation_error_deg(a: Rig, b: Rig) -> float:
    Ra = (invert_transform(a.T_rig_cam["right"]) @ a.T_rig_cam["left"])[:3, :3]
    Rb = (invert_transform(b.T_rig_cam["right"]) @ b.T_rig_cam["left"])[:3, :3]
    return math.degrees(rotation_angle(Ra @ Rb.T))


def true_vertical_disparity(
    recording: Path, truth: Rig, calibration: Rig, vpc: RectifiedPairConfig = VPC
) -> np.ndarray:
    """|v_left − v_right| (VPC px of ``calibration``'s pair) of the scene's true surface points
    (ground-truth depth of every frame) that land in both VPC images."""
    doc = json.loads((recording / "ground_truth" / "scene.json").read_text())
    gt = doc["vpc"]
    cam = PinholeModel(gt["width"], gt["height"], fx=gt["fx"], fy=gt["fy"], cx=gt["cx"], cy=gt["cy"])
    T_rig_rect = np.asarray(doc["T_rig_vpc"]["left"])
    pair = design_rectified_pair(calibration, vpc)
    out = []
    for frame in doc["frames"]:
        depth = np.load(recording / frame["depth"])
        pts, _ = depth_points(depth, cam, T_rig_rect, stride=2)
        rows = {}
        for name in ("left", "right"):
            T = truth.T_rig_cam[name]
            p = (pts.astype(np.float64) - T[:3, 3]) @ T[:3, :3]
            rows[name] = rectified_rows(pair, name, p / np.linalg.norm(p, axis=1, keepdims=True))
        inside = rows["left"][1] & rows["right"][1]
        out.append(np.abs(rows["left"][0][inside, 1] - rows["right"][0][inside, 1]))
    return np.concatenate(out)
