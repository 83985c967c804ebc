"""The rectified VPC pair: derived from the calibrated extrinsics, rows align on any mount."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from calibration.geometry import invert_transform, rotation_angle, transform_points
from rig.errors import ConfigError
from rig.lut import build_rectified_lut
from rig.rectified import RectifiedPair, RectifiedPairConfig, design_rectified_pair
from rig.sim import divergent_rig
from tests.helpers.shots import StereoShot, plane_shot, prototype_rig, room_shot


def project(pair: RectifiedPair, name: str, pts_rig: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pinhole projection of rig-frame points into VPC ``name`` (independent of the LUT)."""
    p = transform_points(invert_transform(pair.T_rig_rect[name]), pts_rig)
    c = pair.camera
    return np.stack([c.fx * p[:, 0] / p[:, 2] + c.cx, c.fy * p[:, 1] / p[:, 2] + c.cy, p[:, 2]], axis=1)


@pytest.mark.parametrize(
    ("angle", "pitch", "roll", "config"),
    [
        (90.0, 0.0, 0.0, RectifiedPairConfig(projection="pinhole")),
        (87.0, 2.0, 0.0, RectifiedPairConfig(projection="pinhole")),
        (93.0, -3.0, 1.5, RectifiedPairConfig(hfov_deg=100, yaw_deg=12.0, pitch_deg=-8.0)),
        (60.0, 1.0, -1.0, RectifiedPairConfig(width=320, height=320, hfov_deg=70)),
    ],
)
def test_rows_align_exactly_on_non_ideal_mounts(
    angle: float, pitch: float, roll: float, config: RectifiedPairConfig
) -> None:
    base = prototype_rig(1.0)
    rig = divergent_rig(base.cameras["left"], base.cameras["right"], 0.072, angle, pitch, roll)
    pair = design_rectified_pair(rig, config)
    assert pair.baseline_m == pytest.approx(rig.baseline())
    # Both VPCs share orientation; their x axis is the baseline; each sits at its camera centre.
    R_l, R_r = pair.T_rig_rect["left"][:3, :3], pair.T_rig_rect["right"][:3, :3]
    assert np.allclose(R_l, R_r) and np.allclose(R_l @ R_l.T, np.eye(3))
    base_dir = (rig.center("right") - rig.center("left")) / rig.baseline()
    assert np.allclose(R_l[:, 0], base_dir)
    for n in ("left", "right"):
        assert np.allclose(pair.T_rig_rect[n][:3, 3], rig.center(n))
        assert np.allclose(rig.T_rig_cam[n][:3, :3] @ pair.R_cam_rect[n], R_l)
    rng = np.random.default_rng(1)
    # Points spread over the VPC's view, 0.2 .. 5 m deep.
    z = rng.uniform(0.2, 5.0, 500)
    u = rng.uniform(0, config.width - 1, 500)
    v = rng.uniform(0, config.height - 1, 500)
    c = pair.camera
    p_rect = np.stack([(u - c.cx) / c.fx * z, (v - c.cy) / c.fy * z, z], axis=1)
    pts = transform_points(pair.T_rig_rect["left"], p_rect)
    pl, pr = project(pair, "left", pts), project(pair, "right", pts)
    assert np.abs(pl[:, 1] - pr[:, 1]).max() < 1e-9, "rows must align"
    assert np.allclose(pl[:, 0] - pr[:, 0], c.fx * pair.baseline_m / z, rtol=1e-9)
    assert np.allclose(pr[:, 2], z)


def test_yaw_is_a_principal_point_shift_and_pitch_a_rotation_about_the_baseline() -> None:
    rig = prototype_rig(1.0)
    straight = design_rectified_pair(rig, RectifiedPairConfig(projection="pinhole"))
    assert straight.camera.cx == pytest.approx(319.5) and straight.camera.fx == pytest.approx(320.0)
    yawed = design_rectified_pair(rig, RectifiedPairConfig(projection="pinhole", yaw_deg=20.0))
    assert np.allclose(yawed.T_rig_rect["left"], straight.T_rig_rect["left"])
    # The centre column now looks 20° to the right of the pair's z axis.
    c = yawed.camera
    assert math.degrees(math.atan2(319.5 - c.cx, c.fx)) == pytest.approx(20.0)
    pitched = design_rectified_pair(rig, RectifiedPairConfig(projection="pinhole", pitch_deg=10.0))
    R = straight.T_rig_rect["left"][:3, :3].T @ pitched.T_rig_rect["left"][:3, :3]
    assert math.degrees(rotation_angle(R)) == pytest.approx(10.0)
    assert np.allclose(R[:, 0], [1.0, 0.0, 0.0]), "a rotation about the baseline (VPC x)"
    # Pitch up: the optical axis tilts towards -y (y points down, docs/design.md).
    z_straight, z_up = straight.T_rig_rect["left"][:3, 2], pitched.T_rig_rect["left"][:3, 2]
    y_straight = straight.T_rig_rect["left"][:3, 1]
    assert z_up @ y_straight == pytest.approx(-math.sin(math.radians(10.0)))
    assert z_up @ z_straight == pytest.approx(math.cos(math.radians(10.0)))
    # A point above the straight pair's centre row lands on the pitched pair's centre row.
    p_rig = straight.T_rig_rect["left"][:3, 3] + 2.0 * z_up
    assert project(straight, "left", p_rig[None])[0, 1] < straight.camera.cy - 50
    assert project(pitched, "left", p_rig[None])[0, 1] == pytest.approx(pitched.camera.cy)
    assert np.allclose(pitched.T_rig_rect["left"][:3, 0], straight.T_rig_rect["left"][:3, 0])


def test_vpc_json_has_exactly_the_contract_keys() -> None:
    pair = design_rectified_pair(prototype_rig(1.0), RectifiedPairConfig(width=800, height=600, hfov_deg=100))
    doc = pair.as_json()
    assert list(doc) == ["projection", "width", "height", "fx", "fy", "cx", "cy", "baseline_m", "R_rig_vpc"]
    assert doc["projection"] == "pinhole" and np.allclose(doc["R_rig_vpc"], pair.T_rig_rect["left"][:3, :3])
    assert doc["width"] == 800 and doc["height"] == 600
    assert doc["fx"] == pytest.approx(400 / math.tan(math.radians(50)))
    assert doc["baseline_m"] == pytest.approx(0.072)


def test_vpc_config_errors() -> None:
    rig = prototype_rig(1.0)
    with pytest.raises(ConfigError, match="no camera 'middle'"):
        design_rectified_pair(rig, RectifiedPairConfig(projection="pinhole", left="middle"))
    with pytest.raises(ValueError, match="hfov_deg"):
        RectifiedPairConfig(hfov_deg=185)
    with pytest.raises(ValueError, match="extra"):
        RectifiedPairConfig(fov=90)  # type: ignore[call-arg]


def _vertical_disparity(
    shot: StereoShot, pair: RectifiedPair
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Matched features on the VPC pair built with ``pair``: (dy, dx) of forward-backward
    consistent KLT tracks from corners of the left VPC image."""
    rig = shot.rig
    left = build_rectified_lut(rig.cameras["left"], pair.R_cam_rect["left"], pair.camera).remap(shot.left)
    right = build_rectified_lut(rig.cameras["right"], pair.R_cam_rect["right"], pair.camera).remap(shot.right)
    pts: Any = cv2.goodFeaturesToTrack(left, 800, 0.01, 5)
    klt: Any = cv2.calcOpticalFlowPyrLK  # its stubs reject None for the output points
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
    fwd, st1, _ = klt(left, right, pts, None, winSize=(21, 21), maxLevel=4, criteria=crit)
    back, st2, _ = klt(right, left, fwd, None, winSize=(21, 21), maxLevel=4, criteria=crit)
    ok = (st1[:, 0] == 1) & (st2[:, 0] == 1) & (np.linalg.norm(back - pts, axis=2)[:, 0] < 0.1)
    assert ok.sum() > 200
    d = (pts - fwd)[ok, 0]
    return d[:, 1], d[:, 0]


SMALL = RectifiedPairConfig(width=320, height=240)
#: Measured |dy| median and 95th percentile (px) on the 87°/2° mount (3 B: docs/stereo.md's figure).
PLANE_DY = {3.0: (0.017, 0.053), 6.0: (0.018, 0.059)}


@pytest.mark.parametrize("k", [3.0, 6.0])
def test_rendered_non_ideal_mount_plane_rows_align_to_a_tenth_of_a_pixel(k: float) -> None:
    """87° mount, right camera pitched 2°: the pair designed from that calibration has rows that
    align (95th percentile of |dy| over matched features ≤ 0.1 px on a textured plane)."""
    shot = plane_shot(k, scale=0.5, vpc=SMALL, angle_deg=87.0, pitch_deg=2.0)
    dy, dx = _vertical_disparity(shot, shot.pair)
    expected = shot.pair.fx / k
    assert abs(np.median(dx) - expected) < 0.5
    p95 = float(np.percentile(np.abs(dy), 95))
    print(
        f"\nplane at {k} B on an 87°/2° mount: |dy| median {np.median(np.abs(dy)):.3f} px, p95 {p95:.3f} px"
    )
    assert p95 <= 0.1
    assert (float(np.median(np.abs(dy))), p95) == pytest.approx(PLANE_DY[k], rel=0.25)


def test_rendered_non_ideal_mount_room_rows_align_and_nominal_design_does_not() -> None:
    """The room (many depths, slanted surfaces): median |dy| ≤ 0.1 px (its 95th percentile is
    ~0.2 px: KLT's own error at occlusion edges). A pair designed from the *nominal* 90° mount
    on the same images is off by pixels: the test can tell."""
    shot = room_shot(0, scale=0.5, vpc=SMALL, angle_deg=87.0, pitch_deg=2.0)
    dy, _ = _vertical_disparity(shot, shot.pair)
    med, p95 = float(np.median(np.abs(dy))), float(np.percentile(np.abs(dy), 95))
    print(f"\nroom on an 87°/2° mount: |dy| median {med:.3f} px, p95 {p95:.3f} px")
    assert med <= 0.1 and p95 <= 0.3
    assert (med, p95) == pytest.approx((0.050, 0.169), rel=0.25)  # measured
    nominal = design_rectified_pair(prototype_rig(0.5), SMALL)
    dy_nominal, _ = _vertical_disparity(shot, nominal)
    nominal_med = float(np.median(np.abs(dy_nominal)))
    print(f"room, pair designed for the nominal 90° mount: |dy| median {nominal_med:.2f} px")
    assert nominal_med > 1.0 and nominal_med == pytest.approx(4.6, rel=0.25)  # measured, docs/stereo.md


def test_the_pair_is_described_by_its_projection_and_real_size() -> None:
    rig = prototype_rig(1.0)
    latlon = design_rectified_pair(rig, RectifiedPairConfig())
    assert latlon.describe() == f"lat-lon {latlon.camera.width}x{latlon.camera.height}, 5.585 px/deg"
    assert (latlon.camera.width, latlon.camera.height) != (640, 480)
    pinhole = design_rectified_pair(rig, RectifiedPairConfig(width=320, height=240, hfov_deg=100))
    assert pinhole.describe() == "pinhole 320x240, hfov 100.0°"
