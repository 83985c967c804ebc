"""Rig.from_relative_pose: the canonical rig frame built from T_right_left (docs/design.md, "Conventions")."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration import ModelError, Rig, create
from calibration.geometry import invert_transform, make_transform, rot_x, rot_y, rot_z

CAM = create("equidistant", 800, 800, fx=254.6, fy=254.6, cx=399.5, cy=399.5, fov_deg=190.0)


def _relative(T_rig_left: np.ndarray, T_rig_right: np.ndarray) -> np.ndarray:
    return invert_transform(T_rig_right) @ T_rig_left


def test_ideal_divergent_mount_is_recovered_exactly() -> None:
    """Ideal 90° mount, 72 mm baseline: the rig frame of the mount itself comes back."""
    b = 0.072
    T_rig_left = make_transform(rot_y(np.radians(-45.0)), [-b / 2, 0.0, 0.0])
    T_rig_right = make_transform(rot_y(np.radians(45.0)), [b / 2, 0.0, 0.0])
    rig = Rig.from_relative_pose(CAM, CAM, _relative(T_rig_left, T_rig_right))
    np.testing.assert_allclose(rig.T_rig_cam["left"], T_rig_left, atol=1e-15)
    np.testing.assert_allclose(rig.T_rig_cam["right"], T_rig_right, atol=1e-15)
    assert rig.baseline() == pytest.approx(b, abs=1e-15)
    assert rig.names == ["left", "right"]


def test_parallel_stereo_gives_identity_rotations() -> None:
    # Right camera 0.11 m to the right: p_right = p_left - (0.11, 0, 0).
    rig = Rig.from_relative_pose(CAM, CAM, make_transform(np.eye(3), [-0.11, 0.0, 0.0]))
    np.testing.assert_allclose(rig.T_rig_cam["left"], make_transform(np.eye(3), [-0.055, 0, 0]), atol=1e-15)
    np.testing.assert_allclose(rig.T_rig_cam["right"], make_transform(np.eye(3), [0.055, 0, 0]), atol=1e-15)


@pytest.mark.parametrize("seed", range(20))
def test_random_poses_satisfy_the_frame_definition(seed: int) -> None:
    rng = np.random.default_rng(seed)
    # A plausible but imperfect mount: ~90° divergence with random pitch/roll/yaw errors.
    yaw = np.radians(45.0 + rng.normal(0.0, 5.0))
    err_l = Rotation.from_rotvec(rng.normal(0.0, 0.05, 3)).as_matrix()
    err_r = Rotation.from_rotvec(rng.normal(0.0, 0.05, 3)).as_matrix()
    T_rig_left = make_transform(rot_y(-yaw) @ err_l, rng.normal(0.0, 0.2, 3))
    T_rig_right = make_transform(rot_y(yaw) @ err_r, rng.normal(0.0, 0.2, 3))
    T_right_left = _relative(T_rig_left, T_rig_right)

    rig = Rig.from_relative_pose(CAM, CAM, T_right_left, names=("a", "b"))
    Ta, Tb = rig.T_rig_cam["a"], rig.T_rig_cam["b"]
    # The relative pose is preserved.
    np.testing.assert_allclose(_relative(Ta, Tb), T_right_left, atol=1e-12)
    # Origin at the midpoint, x along the baseline from a to b.
    ca, cb = Ta[:3, 3], Tb[:3, 3]
    np.testing.assert_allclose(ca + cb, 0.0, atol=1e-12)
    assert ca[1] == pytest.approx(0.0, abs=1e-12) and ca[2] == pytest.approx(0.0, abs=1e-12)
    assert cb[0] > 0.0
    # z is the mean optical axis made orthogonal to x: the axes' mean lies in the x-z plane, z > 0.
    mean_axis = Ta[:3, 2] + Tb[:3, 2]
    assert mean_axis[1] == pytest.approx(0.0, abs=1e-12)
    assert mean_axis[2] > 0.0
    for T in (Ta, Tb):
        R = T[:3, :3]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)


def test_frame_is_independent_of_the_input_pose_origin() -> None:
    """Re-expressing both cameras in another world frame changes nothing: only T_right_left matters."""
    T_rig_left = make_transform(rot_y(-0.8) @ rot_x(0.02), [-0.04, 0.001, 0.0])
    T_rig_right = make_transform(rot_y(0.75) @ rot_z(-0.01), [0.035, -0.002, 0.003])
    T_world_rig = make_transform(rot_z(1.0) @ rot_x(-0.3), [3.0, -2.0, 1.0])
    a = Rig.from_relative_pose(CAM, CAM, _relative(T_rig_left, T_rig_right))
    b = Rig.from_relative_pose(CAM, CAM, _relative(T_world_rig @ T_rig_left, T_world_rig @ T_rig_right))
    for name in ("left", "right"):
        np.testing.assert_allclose(a.T_rig_cam[name], b.T_rig_cam[name], atol=1e-12)


@pytest.mark.parametrize(
    ("T", "message"),
    [
        (np.eye(4), "coincide"),
        # Right camera turned 180° about y and 0.1 m to the right: the optical axes cancel out.
        (invert_transform(make_transform(rot_y(np.pi), [0.1, 0.0, 0.0])), "parallel"),
        (make_transform(2.0 * np.eye(3), [0.1, 0.0, 0.0]), "rigid"),
        (np.full((4, 4), np.nan), "finite"),
        (np.eye(3), "4x4"),
    ],
)
def test_degenerate_poses_raise_model_error(T: np.ndarray, message: str) -> None:
    with pytest.raises(ModelError, match=message):
        Rig.from_relative_pose(CAM, CAM, T)


def test_axis_along_the_baseline_raises() -> None:
    # Both cameras look along +x, the right one 0.1 m further along x: mean axis ∥ baseline.
    T_rig_left = make_transform(rot_y(np.pi / 2), [0.0, 0.0, 0.0])
    T_rig_right = make_transform(rot_y(np.pi / 2), [0.1, 0.0, 0.0])
    with pytest.raises(ModelError, match="parallel"):
        Rig.from_relative_pose(CAM, CAM, _relative(T_rig_left, T_rig_right))


def test_same_names_refused() -> None:
    with pytest.raises(ModelError, match="different names"):
        Rig.from_relative_pose(CAM, CAM, make_transform(np.eye(3), [-0.1, 0, 0]), names=("x", "x"))
